"""The console's receive side keeps the newest message per agent and topic between UI ticks (so a
console of 1,000 agents decodes at most one per tick each) and every event, in arrival order."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, NodeSettings
from antalate_lcm.msgs import hlc_error_t, mc_state_t, telemetry_t
from operator_tui.node import OperatorNode
from tests.harness.polling import wait_for


@pytest.fixture
def node() -> Iterator[OperatorNode]:
    ctx = Context(Buses({"lan": "memq://"}), Executor())
    ctx.executor.start()
    op = OperatorNode(NodeSettings.from_config(parse_config({"buses": {"lan": "memq://"}}), agent="op"), ctx)
    op.start()
    yield op
    op.stop()
    ctx.close()


def _mc(agent: str, state: int, ack: int) -> bytes:
    m = mc_state_t()
    m.header.agent, m.state, m.last_command_seq = agent, state, ack
    return m.encode()


def _error(agent: str, code: int) -> bytes:
    m = hlc_error_t()
    m.header.agent, m.code, m.severity, m.text = agent, code, hlc_error_t.ERROR, f"fault {code}"
    return m.encode()


def test_newest_state_per_channel_and_every_event(node: OperatorNode) -> None:
    bus = node.context.buses
    for ack in range(1, 11):
        bus.publish(
            "lan", "a/MC_STATE", _mc("a", mc_state_t.TAKEOFF if ack < 10 else mc_state_t.MISSION, ack)
        )
        bus.publish("lan", "b/MC_STATE", _mc("b", mc_state_t.STANDBY, 0))
    for code in (1, 2, 3):
        bus.publish("lan", "a/HLC_ERROR", _error("a", code))
    bus.publish("lan", "a/TELEMETRY", telemetry_t().encode())
    bus.publish("lan", "a/NOT_WATCHED", b"whatever")
    assert wait_for(lambda: node.received == 24, 2)  # the unwatched channel never reaches the console
    items = node.drain()
    by_topic = [(i.topic, i.agent) for i in items]
    assert sorted(by_topic) == sorted(
        [
            ("MC_STATE", "a"),
            ("MC_STATE", "b"),
            ("HLC_ERROR", "a"),
            ("HLC_ERROR", "a"),
            ("HLC_ERROR", "a"),
            ("TELEMETRY", "a"),
        ]
    )
    newest = next(i.msg for i in items if i.topic == "MC_STATE" and i.agent == "a")
    assert (newest.state, newest.last_command_seq) == (mc_state_t.MISSION, 10), (
        "the newest carries the newest ack"
    )
    assert [i.msg.code for i in items if i.topic == "HLC_ERROR"] == [1, 2, 3]
    assert [i.received for i in items] == sorted(i.received for i in items), "in arrival order"
    assert node.skipped == 18  # 9 superseded states of each agent, never decoded
    assert node.drain() == []


def test_garbage_in_the_newest_slot_is_counted_not_fatal(node: OperatorNode) -> None:
    bus = node.context.buses
    bus.publish("lan", "a/MC_STATE", _mc("a", mc_state_t.STANDBY, 0))
    bus.publish("lan", "a/MC_STATE", b"\x00garbage")
    assert wait_for(lambda: node.received == 2, 2)
    assert node.drain() == []
    assert node.decode_errors == 1
    bus.publish("lan", "a/MC_STATE", _mc("a", mc_state_t.STANDBY, 0))
    assert wait_for(lambda: node.received == 3, 2)
    assert [i.agent for i in node.drain()] == ["a"]


def test_a_state_republished_unchanged_is_not_decoded_again(node: OperatorNode) -> None:
    bus = node.context.buses
    bus.publish("lan", "a/MC_STATE", _mc("a", mc_state_t.STANDBY, 3))
    assert wait_for(lambda: node.received == 1, 2)
    first = node.drain()[0].msg
    for n, (state, ack) in enumerate([(mc_state_t.STANDBY, 3), (mc_state_t.MISSION, 3)], start=2):
        bus.publish("lan", "a/MC_STATE", _mc("a", state, ack))  # a fresh header each time, like a republish

        def received(n: int = n) -> bool:
            return node.received == n

        assert wait_for(received, 2)
        (item,) = node.drain()
        if state == mc_state_t.STANDBY:
            assert item.msg is first and node.unchanged == 1, "same body: the decoded message stands"
        else:
            assert item.msg is not first and item.msg.state == mc_state_t.MISSION
    assert node.unchanged == 1
