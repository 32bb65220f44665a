"""A node's own settings (`NodeSettings`) and its topics' publishers as handles (`Node.publisher`).

An agent's nodes take their settings from its config; a node that flies nothing (the console, the
scripted operator) takes the swarm's buses, topics and key under a name of its own. Every message is
taken from a real in-process bus (memq://) and checked as a receiving node would check it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from pydantic import ValidationError

from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import operator_cmd_t, telemetry_t
from antalate_lcm.station.client import build_operator_cmd
from antalate_lcm.wire.security import Reason, check_mac
from antalate_lcm.wire.vocabulary import Command
from tests.harness.polling import wait_for

KEY = "node settings test key"
#: A second bus, named in the settings, never opened (no socket outside a namespace): nothing is sent on it.
WAN = "udpm://239.255.76.70:7670?ttl=1"


def _config(**extra: Any) -> Config:
    doc: dict[str, Any] = {
        "agent": {"name": "a-1"},
        "buses": {"lan": "memq://", "wan": WAN},
        "topics": {"TELEMETRY": ["lan", "wan"], "MC_STATE": {"channel": "{agent}/mc"}, "OPERATOR_CMD": "lan"},
        **extra,
    }
    return parse_config(doc, "agent.toml")


def _local(**extra: Any) -> Config:
    """:func:`_config` on the in-process bus alone (what is sent here is sent, and nothing persists)."""
    return _config(buses={"lan": "memq://"}, topics={}, **extra)


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context(Buses({"lan": "memq://"}), Executor())
    ctx.executor.start()
    try:
        yield ctx
    finally:
        ctx.close()


def test_an_agents_settings_carry_its_name_routes_channels_and_key() -> None:
    settings = NodeSettings.from_config(_config(security={"swarm_key": KEY, "window": 2.0}))
    assert settings.agent == "a-1"
    assert dict(settings.buses) == {"lan": "memq://", "wan": WAN}
    assert settings.topic_buses("TELEMETRY") == ("lan", "wan")
    assert settings.topic_buses("HLC_STATE") == ("lan",)  # the default bus
    assert settings.topics["MC_STATE"].channel == "{agent}/mc"
    assert settings.security.swarm_key == KEY and settings.security.window == 2.0


def test_a_node_of_its_own_speaks_under_its_name_on_the_swarms_buses_and_key(context: Context) -> None:
    settings = NodeSettings.from_config(_config(security={"swarm_key": KEY}), agent="operator")
    console = Node(settings, context, watcher=True)
    assert console.agent == "operator" and console.settings.topic_buses("TELEMETRY") == ("lan", "wan")
    assert console.routes.channel("MC_STATE") == "operator/mc"
    assert console.routes.channel("OPERATOR_CMD", agent="a-1") == "a-1/OPERATOR_CMD"
    got: list[bytes] = []
    context.buses.subscribe("lan", "a-1/OPERATOR_CMD", None, lambda _ch, data: got.append(data))
    cmd = operator_cmd_t()
    cmd.command, cmd.target = int(Command.TAKEOFF), "a-1"
    context.executor.run_sync(lambda: console.publish("OPERATOR_CMD", cmd, seq=3, agent="a-1"))
    assert wait_for(lambda: len(got) == 1, 5)
    sent = operator_cmd_t.decode(got[0])
    assert sent.header.agent == "operator" and sent.header.seq == 3
    assert check_mac(sent, [KEY]) is None  # signed with the swarm's key


def test_a_name_that_cannot_be_part_of_a_channel_is_refused() -> None:
    with pytest.raises(ValidationError, match="part of channel names"):
        NodeSettings.from_config(_config(), agent="op/1")


def test_an_unknown_topic_is_named_with_the_known_ones(context: Context) -> None:
    settings = NodeSettings.from_config(_config())
    with pytest.raises(KeyError, match="unknown topic 'NOPE'; known: .*TELEMETRY"):
        settings.topic_buses("NOPE")
    with pytest.raises(KeyError, match="unknown topic 'NOPE'"):
        Node(settings, context).publisher("NOPE")


def test_a_publisher_handle_is_the_topics_one_and_counts_the_seq_with_publish(context: Context) -> None:
    node = Node(NodeSettings.from_config(_local()), context, name="hlc")
    heard: list[telemetry_t] = []
    context.buses.subscribe("lan", "a-1/TELEMETRY", telemetry_t, lambda _ch, m: heard.append(m))
    pub = node.publisher("TELEMETRY")
    assert node.publisher("TELEMETRY") is pub and pub.channel == "a-1/TELEMETRY" and pub.buses == ["lan"]

    def send() -> list[bool]:
        return [
            pub.publish(telemetry_t()),
            node.publish("TELEMETRY", telemetry_t()),
            pub.publish(telemetry_t(), seq=1),  # a resend: the original's seq, the counter untouched
            pub.publish(telemetry_t()),
        ]

    assert context.executor.run_sync(send) == [True] * 4
    assert wait_for(lambda: len(heard) == 4, 5)
    assert [m.header.seq for m in heard] == [1, 2, 1, 3]
    utimes = [m.header.utime for m in heard]
    assert utimes == sorted(set(utimes))  # strictly increasing: no message looks like a replay
    assert all(m.header.agent == "a-1" and m.header.mac_len == 0 for m in heard)  # no key: unsigned


def test_a_publisher_with_template_fields_is_its_own(context: Context) -> None:
    console = Node(NodeSettings.from_config(_config(), agent="operator"), context, watcher=True)
    one, two = console.publisher("OPERATOR_CMD", agent="a-1"), console.publisher("OPERATOR_CMD", agent="a-2")
    assert one is not two and (one.channel, two.channel) == ("a-1/OPERATOR_CMD", "a-2/OPERATOR_CMD")
    assert console.publisher("OPERATOR_CMD", agent="a-1") is one


def test_the_station_clients_commands_are_signed_as_a_nodes_messages_are(context: Context) -> None:
    """One signing code: what the client signs passes an agent's admission; another key's does not."""
    now = int(time.time() * 1e6)
    osc = Node(NodeSettings.from_config(_local(security={"swarm_key": KEY})), context, name="osc")
    signed = build_operator_cmd("TAKEOFF", target="a-1", sender="op", seq=1, utime=now, key=KEY)
    assert osc.admission.vet_relay(signed, signed=True, channel="a-1/OPERATOR_CMD") is None
    forged = build_operator_cmd("TAKEOFF", target="a-1", sender="op", seq=2, utime=now, key="another key")
    refusal = osc.admission.vet_relay(forged, signed=True, channel="a-1/OPERATOR_CMD")
    assert refusal is not None and refusal.reason == Reason.FORGED.value
    unsigned = build_operator_cmd("TAKEOFF", target="a-1", sender="op", seq=3, utime=now, key=None)
    assert unsigned.header.mac_len == 0
