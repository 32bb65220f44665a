"""What a node's handlers receive when no admission is needed (no swarm key, a type with no input
check), beside the path with the admission forced on: `Node.subscribe` hands its handler to the bus
(``msg_only``) and `Node.subscribe_all` skips `NodeAdmission.admit`, which could only say yes; a type
with an input check still goes through it, and an invalid message is still dropped."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import pytest

from antalate_lcm.core.admission import NodeAdmission
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import velocity_cmd_t
from tests.harness.messages import mc_state


class _Listener(Node):
    kind = "listener"

    def __init__(self, settings: NodeSettings, context: Context) -> None:
        super().__init__(settings, context, watcher=True)
        self.got: list[tuple[str, Any, str | None]] = []

    def on_start(self) -> None:
        self.subscribe("MC_STATE", lambda m: self.got.append(("one", m.header.seq, None)))
        self.subscribe("VELOCITY_CMD", lambda m: self.got.append(("velocity", m.vx, None)))
        self.subscribe_all("MC_STATE", self._all)
        self.subscribe_all("VELOCITY_CMD", self._all)

    def _all(self, msg: Any, match: TopicMatch) -> None:
        self.got.append((match.channel, msg.header.seq, match.fields.get("agent")))


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context.in_process({"lan": "memq://"})
    ctx.executor.start()
    yield ctx
    ctx.close()


def _velocity(vx: float, seq: int) -> velocity_cmd_t:
    msg = velocity_cmd_t()
    msg.vx, msg.header.seq = vx, seq
    return msg


def _run(context: Context, forced: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[list[Any], int]:
    calls = [0]
    real = NodeAdmission.admit

    def counted(self: NodeAdmission, channel: str, msg: Any, sender: str | None) -> bool:
        calls[0] += 1
        return real(self, channel, msg, sender)

    monkeypatch.setattr(NodeAdmission, "admit", counted)
    if forced:
        monkeypatch.setattr(NodeAdmission, "needs_admission", lambda self, t: True)
    settings = NodeSettings.from_config(
        parse_config({"agent": {"name": "alpha"}, "buses": {"lan": "memq://"}})
    )
    node = _Listener(settings, context)
    node.start()
    buses = context.buses
    try:
        for bus in ("lan", context.inproc_bus or "lan"):
            for agent in ("alpha", "bravo"):
                buses.publish(bus, f"{agent}/MC_STATE", mc_state(1, 7))
                buses.publish(bus, f"{agent}/VELOCITY_CMD", _velocity(1.5, 8))
                buses.publish(bus, f"{agent}/VELOCITY_CMD", _velocity(math.nan, 9))  # invalid
        context.executor.run_sync(lambda: None)
        context.executor.run_sync(lambda: None)
    finally:
        node.stop()
        monkeypatch.undo()
    return node.got, calls[0]


def test_without_admission_the_handlers_get_what_the_admitted_path_gives(
    context: Context, monkeypatch: pytest.MonkeyPatch
) -> None:
    plain, plain_calls = _run(context, False, monkeypatch)
    forced, forced_calls = _run(context, True, monkeypatch)
    assert plain == forced
    assert ("one", 7, None) in plain and ("velocity", 1.5, None) in plain
    assert ("bravo/MC_STATE", 7, "bravo") in plain and ("bravo/VELOCITY_CMD", 8, "bravo") in plain
    assert not any(v == 9 or (isinstance(v, float) and math.isnan(v)) for _, v, _ in plain), (
        "the invalid velocity is dropped on both paths"
    )
    assert 0 < plain_calls < forced_calls, "admit is called for the checked type only"
