"""The vehicle kit (antalate_lcm/vehicles/kit): the params parser, the in-memory pipe, link age and
the worker threads every adapter and emulator is built on; and, for each adapter, that its params are
documented and its example config loads."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from antalate_lcm.base.errors import LinkClosed
from antalate_lcm.vehicles import load_adapter
from antalate_lcm.vehicles.kit import LinkAge, LinkedAdapter, MemoryPipe, Workers, defaults, parse_params
from antalate_lcm.vehicles.mavlink import Params as MavlinkParams
from tests import REPO
from tests.harness.polling import wait_for


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        ({"conection": "tcp:x:1"}, "mavlink autopilot parameter 'conection': Extra inputs are not permitted"),
        ({"conection": "tcp:x:1"}, "(known: ['ack_timeout', 'baud'"),  # a misspelt key: the known ones
        ({"baud": "57600"}, "parameter 'baud': Input should be a valid integer"),  # strict: no coercion
        ({"ack_timeout": float("inf")}, "parameter 'ack_timeout'"),  # finite: a timeout of inf never fires
        ({"stream_rate_hz": 1.0}, "mavlink autopilot parameters: Value error, link_stale_after"),
    ],
)
def test_parse_params_names_the_adapter_and_the_key(raw: dict[str, Any], words: str) -> None:
    with pytest.raises(ValueError) as err:
        parse_params(MavlinkParams, raw, "mavlink")
    assert words in str(err.value)


def test_parse_params_takes_none_as_an_empty_table_and_defaults_are_the_fields() -> None:
    assert parse_params(MavlinkParams, None, "mavlink") == MavlinkParams()
    assert defaults(MavlinkParams) == MavlinkParams().model_dump()


def test_an_adapter_without_params_model_or_link_says_so() -> None:
    class Bare(LinkedAdapter[Any, Any]):
        name = "bare"

        def connect(self) -> None: ...
        def close(self) -> None: ...
        def arm(self) -> bool:
            return False

        def disarm(self) -> None: ...
        def takeoff(self, alt: float) -> None: ...
        def land(self) -> None: ...
        def rtl(self) -> None: ...
        def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Any) -> None: ...
        def state(self) -> Any: ...

    with pytest.raises(TypeError, match="needs a params_model"):
        Bare({})
    Bare.params_model = MavlinkParams
    ap = Bare({})
    with pytest.raises(TypeError, match="the bare adapter has no link of its own: pass link="):
        ap._opener(ap._p)


def test_memory_pipe_sends_to_the_peer_queues_its_answers_and_refuses_once_closed() -> None:
    got: list[str] = []
    pipe: MemoryPipe[str, int] = MemoryPipe(got.append)
    pipe.send("a")
    pipe.push(1)
    pipe.push(2)
    assert got == ["a"]
    assert pipe.take(0) == 1 and pipe.drain() == [2] and pipe.take(0.01) is None
    pipe.close()
    pipe.push(3)  # the peer's packet to a closed link goes nowhere
    with pytest.raises(LinkClosed, match="memory link closed"):
        pipe.send("b")
    assert isinstance(LinkClosed(), OSError)  # an adapter's OSError handling covers it
    pipe.open()
    assert pipe.drain() == [] and got == ["a"]
    pipe.send("c")
    assert got == ["a", "c"]


def test_memory_pipe_take_waits_for_a_push_from_another_thread() -> None:
    pipe: MemoryPipe[None, str] = MemoryPipe(lambda _: None)
    threading.Timer(0.05, pipe.push, ("late",)).start()
    assert pipe.take(None) == "late"


def test_link_age_is_infinite_until_heard_then_counts_on_the_clock() -> None:
    now = [100.0]
    age = LinkAge(lambda: now[0])
    assert age() == float("inf") and age.heard_at is None
    age.heard()
    now[0] = 102.5
    assert age() == 2.5
    age.heard(at=103.0)  # a stamp ahead of the clock reads as 0, never negative
    assert age() == 0.0


def test_workers_start_stop_and_a_loop_may_halt_its_own_workers() -> None:
    workers = Workers()
    ticks: list[int] = []

    def loop() -> None:
        while not workers.stop.wait(0.01):
            ticks.append(1)

    def halting() -> None:
        workers.halt()  # from inside a loop: no join of itself

    workers.start((loop, "kit-test-loop"))
    assert workers.running
    wait_for(lambda: len(ticks) >= 2, 5)
    workers.halt()
    assert not workers.running and workers.stop.is_set()
    count = len(ticks)
    threading.Event().wait(0.05)
    assert len(ticks) == count  # joined: the loop ticks no more
    workers.start((halting, "kit-test-halting"))
    wait_for(lambda: not workers.running, 5)
    workers.halt()  # idempotent


@pytest.mark.parametrize(
    ("adapter", "doc", "example"),
    [
        ("crazyflie", "crazyflie.md", "crazyflie.toml"),
        ("mavlink", "ardupilot.md", "arducopter_sitl.toml"),
        ("tello", "tello.md", "tello.toml"),
    ],
)
def test_params_documented_and_example_valid(adapter: str, doc: str, example: str) -> None:
    """Every parameter is in the adapter's docs page and example config, and the example loads."""
    from antalate_lcm.core.config import load_config
    from antalate_lcm.runtime.agent import validate

    cls = load_adapter(adapter)
    text = (REPO / "docs" / doc).read_text()
    config = load_config(REPO / "examples" / example)
    validate(config)
    assert config.hlc.autopilot == adapter
    params = config.hlc.autopilot_params
    cls(params)
    assert cls.params_model is not None
    missing = [k for k in defaults(cls.params_model) if f"`{k}`" not in text or k not in params]
    assert not missing, missing
