"""The bus on memq:// (in-process) and over real UDP multicast in a private namespace."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import IO

import pytest

from antalate_lcm.base.errors import MulticastUnavailable
from antalate_lcm.core.bus import Buses, Subscription
from antalate_lcm.msgs import mc_state_t, telemetry_t
from tests import REPO
from tests.conftest import MCAST_URL, Probe
from tests.harness.messages import mc_state
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for


@pytest.fixture
def bus() -> Iterator[Buses]:
    b = Buses({"test": "memq://"})
    yield b
    b.close()


def test_typed_publish_subscribe(bus: Buses) -> None:
    got: list[tuple[str, int]] = []
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: got.append((ch, m.state)))
    bus.subscribe("test", "b/MC_STATE", mc_state_t, lambda ch, m: got.append((ch, -1)))
    bus.publish("test", "a/MC_STATE", mc_state(mc_state_t.MISSION))
    assert wait_for(lambda: got, 2) == [("a/MC_STATE", mc_state_t.MISSION)]


def test_regex_subscription_sees_every_agent(bus: Buses) -> None:
    got: list[str] = []
    bus.subscribe("test", r"[^/]+/MC_STATE", mc_state_t, lambda ch, m: got.append(ch), regex=True)
    for agent in ("a", "b", "c"):
        bus.publish("test", f"{agent}/MC_STATE", mc_state(1))
    bus.publish("test", "a/HLC_STATE", b"not for us")
    assert wait_for(lambda: len(got) == 3, 2)
    assert sorted(got) == ["a/MC_STATE", "b/MC_STATE", "c/MC_STATE"]


def test_garbage_is_counted_and_logged_at_a_limited_rate(
    bus: Buses, caplog: pytest.LogCaptureFixture
) -> None:
    good: list[int] = []
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: good.append(m.state))
    caplog.set_level(logging.WARNING, logger="antalate.bus")
    wrong_type = telemetry_t().encode()
    truncated = mc_state(3).encode()[:-3]
    for _ in range(50):
        for data in (b"\x00\x01garbage", wrong_type, truncated, b""):
            bus.publish("test", "a/MC_STATE", data)
    bus.publish("test", "a/MC_STATE", mc_state(3))
    assert wait_for(lambda: good, 2) == [3]
    assert bus.decode_errors() == {"a/MC_STATE": 200}
    logged = [r for r in caplog.records if "not a valid mc_state_t" in r.getMessage()]
    assert len(logged) == 1, "one line per channel per minute"


def test_a_burst_is_not_dropped(bus: Buses) -> None:
    got: list[int] = []
    done = threading.Event()

    def slow_handler(ch: str, m: mc_state_t) -> None:
        if not got:
            time.sleep(0.2)  # the dispatcher is busy while the burst queues up
        got.append(m.header.seq)
        if len(got) == 5000:
            done.set()

    bus.subscribe("test", "a/MC_STATE", mc_state_t, slow_handler)
    for i in range(5000):
        bus.publish("test", "a/MC_STATE", mc_state(1, i))
    assert done.wait(10), f"received {len(got)} of 5000"
    assert got == list(range(5000))


def _subscribe_once(bus: Buses, got: list[int]) -> None:
    """A subscriber to a/MC_STATE that records the first message's seq and unsubscribes itself from
    inside its handler."""
    holder: dict[str, Subscription] = {}

    def once(ch: str, m: mc_state_t) -> None:
        got.append(m.header.seq)
        bus.unsubscribe(holder["sub"])

    holder["sub"] = bus.subscribe("test", "a/MC_STATE", mc_state_t, once)


def test_unsubscribe_inside_a_handler(bus: Buses) -> None:
    got: list[int] = []
    _subscribe_once(bus, got)
    other: list[int] = []
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: other.append(m.header.seq))
    for i in range(20):
        bus.publish("test", "a/MC_STATE", mc_state(1, i))
    assert wait_for(lambda: len(other) == 20, 2)
    assert got == [0]


def test_the_last_subscriber_leaving_from_its_handler_releases_the_channel(bus: Buses) -> None:
    """The LCM subscription itself goes (on the dispatcher thread, after the handler); a new
    subscriber on the same channel then gets each message exactly once."""
    first: list[int] = []
    _subscribe_once(bus, first)
    bus.publish("test", "a/MC_STATE", mc_state(1, 0))
    assert wait_for(lambda: first == [0], 2)
    again: list[int] = []
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: again.append(m.header.seq))
    for i in range(1, 11):
        bus.publish("test", "a/MC_STATE", mc_state(1, i))
    assert wait_for(lambda: len(again) >= 10, 2)
    time.sleep(0.2)
    assert again == list(range(1, 11)) and first == [0]


def test_a_raising_handler_does_not_stop_the_bus(bus: Buses) -> None:
    got: list[int] = []

    def bad(ch: str, m: mc_state_t) -> None:
        raise RuntimeError("boom")

    bus.subscribe("test", "a/MC_STATE", mc_state_t, bad)
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: got.append(m.state))
    bus.publish("test", "a/MC_STATE", mc_state(1))
    bus.publish("test", "a/MC_STATE", mc_state(2))
    assert wait_for(lambda: got == [1, 2], 2)


def test_close_leaves_no_thread_and_no_socket() -> None:
    def fds() -> int:
        return len(os.listdir("/proc/self/fd"))

    before_threads, before_fds = threading.active_count(), fds()
    for _ in range(5):
        b = Buses({"x": "memq://", "y": "memq://?"})
        b.open()
        b.subscribe("x", "c", None, lambda ch, d: None)
        b.close()
        b.close()  # idempotent
    import gc

    gc.collect()
    # at most as many as before: a test before this one on the same worker may still be closing its own
    assert threading.active_count() <= before_threads
    assert fds() <= before_fds


def test_unknown_bus_is_a_clear_error(bus: Buses) -> None:
    with pytest.raises(KeyError, match="unknown bus 'lan'; declared: test"):
        bus.publish("lan", "x", b"")


# --------------------------------------------------------------------------- real multicast


def _subscriber(netns: NetNamespace, mode: str) -> tuple[subprocess.Popen[str], IO[str]]:
    """tests/children/bus_subscriber.py in ``mode``, ready (subscribed): the process and its stdout."""
    sub = netns.python(
        "-m", "tests.children.bus_subscriber", MCAST_URL, mode, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert sub.stdout is not None and sub.stdout.readline().strip() == "ready"
    return sub, sub.stdout


def test_two_processes_over_multicast(netns: NetNamespace, probe: Probe) -> None:
    _, out = _subscriber(netns, "order")
    pub = netns.python("-m", "tests.children.bus_publisher", MCAST_URL, stderr=subprocess.PIPE)
    assert pub.wait(20) == 0
    assert out.readline().split() == ["200", "True"]
    # the probe (a third process, raw lcm) saw the same stream
    seen = probe.history("alpha/TELEMETRY", "telemetry_t")
    assert len(seen) == 200 and seen[-1]["mode"] == "SIM"


def test_garbage_datagrams_over_multicast_do_not_kill_a_subscriber(netns: NetNamespace, probe: Probe) -> None:
    sub, out = _subscriber(netns, "decode-errors")
    for data in (b"\xff" * 40, telemetry_t().encode()[:10], b"x"):
        probe.raw("alpha/TELEMETRY", data)
    pub = netns.python("-m", "tests.children.bus_publisher", MCAST_URL, stderr=subprocess.PIPE)
    assert pub.wait(20) == 0
    assert out.readline().split() == ["200", "3"]
    assert sub.wait(5) == 0


def test_no_multicast_route_gives_the_fix() -> None:
    """In a namespace without the route, the CLI prints one clear message with the exact command."""
    from tests.harness.netns import run_unrouted

    argv = [sys.executable, "-m", "tests.children.open_bus", "udpm://239.255.76.67:7667?ttl=1"]
    proc = run_unrouted(argv, timeout=30, cwd=REPO)
    assert proc.returncode != 0
    assert "MulticastUnavailable" in proc.stderr
    assert "ip route add 224.0.0.0/4 dev lo" in proc.stderr
    assert "memq://" in proc.stderr
    assert "Couldn't create LCM" not in proc.stderr, "liblcm's own noise is replaced by ours"
    assert issubclass(MulticastUnavailable, Exception)


def test_a_bad_datagram_is_one_decode_error_however_many_subscribers(bus: Buses) -> None:
    """Counted per datagram, not per subscriber: three subscribers of a channel, one garbage datagram."""
    good: list[int] = []
    for _ in range(3):
        bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: good.append(m.state))
    bus.subscribe("test", r"a/.*", mc_state_t, lambda ch, m: good.append(m.state), regex=True)
    bus.publish("test", "a/MC_STATE", b"\x00garbage\x01")
    bus.publish("test", "a/MC_STATE", mc_state(3))
    assert wait_for(lambda: len(good) == 4, 2)
    assert bus.decode_errors() == {"a/MC_STATE": 1}


def test_an_attached_bus_delivers_on_the_executors_thread_with_no_hop() -> None:
    """Context attaches its bus: handlers run on the nodes' loop thread, and no bus thread exists."""
    from antalate_lcm.core.executor import Executor

    ex = Executor(name="the-one-loop")
    b = Buses({"test": "memq://"})
    b.attach(ex)
    ex.start()
    try:
        threads: list[str] = []
        b.subscribe(
            "test", "a/MC_STATE", mc_state_t, lambda ch, m: threads.append(threading.current_thread().name)
        )
        b.publish("test", "a/MC_STATE", mc_state(1))
        assert wait_for(lambda: threads, 2) == ["the-one-loop"]
        assert "lcm-dispatch" not in {t.name for t in threading.enumerate()}
        with pytest.raises(RuntimeError, match="another executor"):
            b.attach(Executor())
    finally:
        ex.stop()
        b.close()


def test_unsubscribe_from_another_thread_releases_the_channel(bus: Buses) -> None:
    got: list[int] = []
    sub = bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: got.append(m.header.seq))
    bus.publish("test", "a/MC_STATE", mc_state(1, 1))
    assert wait_for(lambda: got == [1], 2)
    bus.unsubscribe(sub)
    link = bus._by_name["test"]
    assert wait_for(lambda: not link._retire, 2), (
        "the LCM subscription is dropped on the loop without a datagram"
    )
    bus.publish("test", "a/MC_STATE", mc_state(1, 2))
    time.sleep(0.1)
    assert got == [1]


def test_releasing_one_channel_of_many_leaves_the_others_delivered(bus: Buses) -> None:
    """A thousand agents' nodes stop one subscription at a time: each release drops its own
    channel's route and no other (the table is copied without it, not rebuilt)."""
    got: list[str] = []
    subs = {
        agent: bus.subscribe("test", f"{agent}/MC_STATE", mc_state_t, lambda ch, m: got.append(ch))
        for agent in ("a", "b", "c")
    }
    bus.unsubscribe(subs["b"])
    for agent in ("a", "b", "c"):
        bus.publish("test", f"{agent}/MC_STATE", mc_state(1))
    assert wait_for(lambda: len(got) == 2, 2)
    time.sleep(0.1)
    assert got == ["a/MC_STATE", "c/MC_STATE"]
    assert sorted(bus._by_name["test"]._routes) == ["a/MC_STATE", "c/MC_STATE"]


def test_subscribers_of_one_type_get_one_decoded_message_and_a_raw_one_the_bytes(bus: Buses) -> None:
    """Two subscribers of a channel and type share one decode (one message object, as documented:
    a handler must not change what it is given); a raw subscriber beside them gets the bytes; after
    the others leave, the last one still gets every message."""
    got: list[tuple[str, object]] = []
    one = bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: got.append(("one", m)))
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: got.append(("two", m)))
    bus.publish("test", "a/MC_STATE", mc_state(3, 5))
    assert wait_for(lambda: len(got) == 2, 2)
    assert [who for who, _ in got] == ["one", "two"] and got[0][1] is got[1][1]
    assert isinstance(got[0][1], mc_state_t) and got[0][1].state == 3 and got[0][1].header.seq == 5
    raw = bus.subscribe("test", "a/MC_STATE", None, lambda ch, d: got.append(("raw", d)))
    got.clear()
    bus.publish("test", "a/MC_STATE", mc_state(4, 6))
    assert wait_for(lambda: len(got) == 3, 2)
    assert [who for who, _ in got] == ["one", "two", "raw"] and isinstance(got[2][1], bytes)
    bus.unsubscribe(one)
    bus.unsubscribe(raw)
    got.clear()
    bus.publish("test", "a/MC_STATE", mc_state(5, 7))
    assert wait_for(lambda: got, 2) and [who for who, _ in got] == ["two"]
    assert bus.decode_errors() == {}


def test_memq_drops_what_nobody_in_the_process_subscribes_to_and_delivers_the_rest() -> None:
    """memq:// is private to its instance: a channel without subscribers goes nowhere, and one
    with a subscriber (exact or pattern) is delivered as before, on
    the loop, in publish order, without liblcm's notify pipe (no system call per message)."""
    import select

    from antalate_lcm.core.executor import Executor

    ex = Executor()  # not started yet: whatever is queued stays queued
    b = Buses({"test": "memq://"})
    b.attach(ex)
    try:
        exact: list[int] = []
        b.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: exact.append(m.header.seq))
        fd = b._connection("test")._lcm.fileno()
        for _ in range(100):
            b.publish("test", "a/TELEMETRY", b"nobody listens")
        b.publish("test", "a/MC_STATE", mc_state(1, 7))
        b.publish("test", "a/MC_STATE", mc_state(1, 8))
        assert exact == [], "never delivered inside the publisher's call"
        assert select.select([fd], [], [], 0)[0] == [], "liblcm's memq queue is not used"
        ex.start()
        assert wait_for(lambda: exact == [7, 8], 2)
        pattern: list[str] = []
        b.subscribe("test", r".*/TELEMETRY", None, lambda ch, d: pattern.append(ch), regex=True)
        b.publish("test", "a/TELEMETRY", b"now someone does")
        assert wait_for(lambda: pattern == ["a/TELEMETRY"], 2)
    finally:
        ex.stop()
        b.close()


def test_msg_only_gets_what_the_handler_would_without_the_channel(bus: Buses) -> None:
    """``msg_only`` (a node's handler with nothing to admit, `Node.subscribe`) against the
    two-argument handler it stands in for: the same decoded messages, alone and beside subscribers
    of another type (`_deliver`), a raising one contained, and no pattern may have one."""
    via_handler: list[object] = []
    via_message: list[object] = []
    bus.subscribe("test", "a/MC_STATE", mc_state_t, lambda ch, m: via_handler.append(m))
    bus.subscribe("test", "a/MC_STATE", mc_state_t, via_message.append, msg_only=True)
    bus.publish("test", "a/MC_STATE", mc_state(3, 5))
    assert wait_for(lambda: len(via_message) == 1 and len(via_handler) == 1, 2)
    assert via_message[0] is via_handler[0]
    raw = bus.subscribe("test", "a/MC_STATE", None, lambda ch, d: via_handler.append(d))  # mixed types
    bus.publish("test", "a/MC_STATE", mc_state(4, 6))
    assert wait_for(lambda: len(via_handler) == 3 and len(via_message) == 2, 2)
    assert via_message[1] is via_handler[1] and isinstance(via_handler[2], bytes)
    bus.unsubscribe(raw)

    def boom(msg: object) -> None:
        raise RuntimeError("handler bug")

    bus.subscribe("test", "b/MC_STATE", mc_state_t, boom, msg_only=True)
    bus.subscribe("test", "b/MC_STATE", mc_state_t, lambda ch, m: via_handler.append(m))
    bus.publish("test", "b/MC_STATE", mc_state(5, 7))
    assert wait_for(lambda: len(via_handler) == 4, 2)
    with pytest.raises(ValueError, match="exact channel"):
        bus.subscribe("test", r".*", mc_state_t, print, regex=True, msg_only=True)
