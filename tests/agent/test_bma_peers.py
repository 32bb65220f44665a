"""Peers in the behavior contract: ``ctx.peers`` fed by the BMA (docs/behaviors.md, "Peers"), an
agent's own messages heard once, and a config that would split the swarm refused at start."""

from __future__ import annotations

import contextlib
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from antalate_lcm.agent.bma import BmaNode
from antalate_lcm.base import geo
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.core.behavior import Behavior
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import mc_state_t, telemetry_t
from antalate_lcm.wire.peers import PeerTable
from behaviors.swarm_rules.behavior import Flocking
from tests import REPO
from tests.harness.polling import wait_for
from tests.harness.process import run_antalate

KEY = "peer-test-key"
HOME = (32.7767, 35.0231)


class PeerReader(Behavior):
    """Keeps the table it is given (the test reads it on the executor thread)."""

    uses_peers = True

    def on_activate(self) -> None:
        self.table: PeerTable = self.ctx.peers


class Undeclared(Behavior):
    """Reads ctx.peers without declaring uses_peers: a plugin bug, reported as its failure."""

    def on_activate(self) -> None:
        self.ctx.peers.peers(self.ctx.now)


def _config(agent: str, plugin: str = "tests.agent.test_bma_peers:PeerReader", key: str = KEY) -> Config:
    return parse_config(
        {
            "agent": {"name": agent},
            "buses": {"lan": "memq://"},
            "security": {"swarm_key": key},
            "bma": [{"name": "swarm", "behaviors": [{"plugin": plugin, "activate_on": ["STANDBY"]}]}],
        },
        f"{agent}.toml",
    )


@pytest.fixture
def context() -> Iterator[Context]:
    """One process holding the whole swarm, as ``antalate agent`` without --processes."""
    ctx = Context.in_process({"lan": "memq://"}, whole_swarm=True)
    ctx.executor.start()
    yield ctx
    ctx.close()


def _telemetry(north: float, east: float, alt: float = 5.0) -> telemetry_t:
    msg = telemetry_t()
    msg.lat, msg.lon = geo.offset(*HOME, north, east)
    msg.alt, msg.heading, msg.vn, msg.ve = alt, 90.0, 1.0, 0.5
    return msg


def _state(value: int) -> mc_state_t:
    msg = mc_state_t()
    msg.state = value
    return msg


def test_a_behavior_that_declares_uses_peers_gets_every_other_agent(context: Context) -> None:
    cfg = _config("a1")
    nodes: list[Node] = [
        Node(NodeSettings.from_config(_config(n)), context, name="hlc") for n in ("a1", "b", "c")
    ]
    forger = Node(NodeSettings.from_config(_config("x", key="another-key")), context, name="hlc")
    bma = BmaNode(cfg, context, cfg.bma[0])
    for node in [*nodes, forger, bma]:
        context.executor.run_sync(node.start)
    me, b, c = nodes

    def publish() -> None:
        me.publish("MC_STATE", _state(mc_state_t.STANDBY))
        me.publish("TELEMETRY", _telemetry(0.0, 0.0))
        b.publish("MC_STATE", _state(mc_state_t.MISSION))
        b.publish("TELEMETRY", _telemetry(10.0, 0.0))
        c.publish("TELEMETRY", _telemetry(0.0, -6.0, alt=7.0))
        forger.publish("TELEMETRY", _telemetry(1.0, 1.0))  # signed with another key: never a peer

    context.executor.run_sync(publish)
    assert wait_for(lambda: bma.active() == ["PeerReader"], 5)

    def snapshot() -> dict[str, Any]:
        behavior = bma.behavior("PeerReader")
        table: PeerTable = behavior.table  # type: ignore[union-attr]
        now = context.executor.clock()
        return {
            "me": table.me and table.me.agent,
            "peers": {
                p.agent: (round(p.north, 2), round(p.east, 2), p.up, p.mc_state) for p in table.peers(now)
            },
        }

    def complete() -> bool:
        context.executor.run_sync(publish)
        return len(context.executor.run_sync(snapshot)["peers"]) == 2

    assert wait_for(complete, 5)
    got = context.executor.run_sync(snapshot)
    assert got["me"] == "a1"
    assert got["peers"] == {"b": (10.0, 0.0, 5.0, "MISSION"), "c": (0.0, -6.0, 7.0, None)}
    auth = bma.admission.authenticator
    assert auth is not None and auth.rejected and all(r.value != "replayed" for r in auth.rejected)


def test_reading_peers_without_declaring_them_fails_the_behavior(context: Context) -> None:
    cfg = _config("a1", plugin="tests.agent.test_bma_peers:Undeclared")
    bma = BmaNode(cfg, context, cfg.bma[0])
    assert bma.peers is None  # nobody declared uses_peers: the BMA does not listen
    hlc = Node(NodeSettings.from_config(cfg), context, name="hlc")
    for node in (hlc, bma):
        context.executor.run_sync(node.start)
    context.executor.run_sync(lambda: hlc.publish("MC_STATE", _state(mc_state_t.STANDBY)))
    assert wait_for(lambda: "Undeclared" in bma.failures(), 5)
    assert "does not declare uses_peers = True" in bma.failures()["Undeclared"]


def test_an_agents_own_telemetry_reaches_its_node_once_with_a_swarm_key(context: Context) -> None:
    """subscribe + subscribe_all of one node, one process: each handler once per message, no replay.

    Before the fix the own channel came twice (the in-process copy and the network one, decoded
    apart), and the replay guard logged "dropped telemetry_t ... replayed or out of order".
    """
    cfg = _config("a1")
    settings = NodeSettings.from_config(cfg)
    hlc, bma = Node(settings, context, name="hlc"), Node(settings, context, name="bma")
    own: list[int] = []
    everyone: list[tuple[str, int]] = []

    def listen() -> None:
        bma.subscribe("TELEMETRY", lambda m: own.append(m.header.seq))
        bma.subscribe_all(
            "TELEMETRY", lambda m, match: everyone.append((match.fields["agent"], m.header.seq))
        )

    for node in (hlc, bma):
        context.executor.run_sync(node.start)
    context.executor.run_sync(listen)
    for _ in range(20):
        context.executor.run_sync(lambda: hlc.publish("TELEMETRY", _telemetry(0.0, 0.0)))
    assert wait_for(lambda: len(own) == 20 and len(everyone) == 20, 5), (len(own), len(everyone))
    context.executor.run_sync(lambda: None)
    assert own == list(range(1, 21)) and everyone == [("a1", s) for s in range(1, 21)]
    auth = bma.admission.authenticator
    assert auth is not None and auth.rejected == {} and auth.accepted == 40


def test_unsubscribing_subscribe_all_drops_its_own_channel_half(context: Context) -> None:
    cfg = _config("a1")
    settings = NodeSettings.from_config(cfg)
    hlc, bma = Node(settings, context, name="hlc"), Node(settings, context, name="bma")
    got: list[TopicMatch] = []
    for node in (hlc, bma):
        context.executor.run_sync(node.start)
    sub = context.executor.run_sync(
        lambda: bma.subscribe_all("TELEMETRY", lambda m, match: got.append(match))
    )
    context.executor.run_sync(lambda: bma.unsubscribe(sub))
    context.executor.run_sync(lambda: hlc.publish("TELEMETRY", _telemetry(0.0, 0.0)))
    context.executor.run_sync(lambda: None)
    assert not wait_for(lambda: got, 0.3)


def test_a_peer_bus_inside_one_process_is_refused_when_the_agents_are_not(context: Context) -> None:
    """A BMA in a process of its own (``antalate bma``), or one shard of ``--processes N``."""
    cfg = _config("a1")
    with (
        contextlib.closing(Context(Buses(cfg.buses), Executor())) as alone,
        pytest.raises(ConfigError, match=r"buses\.lan: a bus other processes reach .* TELEMETRY"),
    ):
        BmaNode(cfg, alone, cfg.bma[0])
    BmaNode(cfg, context, cfg.bma[0])  # the whole swarm in this process: memq:// reaches everyone


@pytest.mark.parametrize(
    "how",
    [["agent", "--agents", "4", "--processes", "2"], ["bma", "--name", "swarm"]],
    ids=["processes-2", "bma-alone"],
)
def test_a_behavior_that_cannot_hear_its_peers_stops_the_start_with_one_line(
    tmp_path: Path, how: list[str]
) -> None:
    doc = {
        "agent": {"name": "g"},
        "buses": {"lan": "memq://"},
        "bma": [{"name": "swarm", "behaviors": [{"plugin": "gathering"}]}],
    }
    cfg = tmp_path / "swarm.toml"
    cfg.write_text(tomli_w.dumps(doc))
    proc = run_antalate(how[0], str(cfg), *how[1:], cwd=REPO)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"antalate: invalid config {cfg}: buses.lan: a bus other processes reach")
    assert "bma[0].behaviors[0]" in lines[0] and "'memq://'" in lines[0]


def test_flocking_sets_off_along_its_heading_or_one_fixed_by_the_agents_name(context: Context) -> None:
    """``heading`` given (0 included) is the rule's; omitted, each agent takes one from its name, so the
    flock starts in disorder (docs/behaviors.md, flocking)."""

    def heading(agent: str, params: dict[str, Any]) -> float:
        behaviors = [{"plugin": "flocking", "params": params}]
        doc = {
            "agent": {"name": agent},
            "buses": {"lan": "memq://"},
            "bma": [{"name": "swarm", "behaviors": behaviors}],
        }
        cfg = parse_config(doc, f"{agent}.toml")
        bma = BmaNode(cfg, context, cfg.bma[0])
        context.executor.run_sync(bma.start)
        flocking = bma.behavior("flocking")
        assert isinstance(flocking, Flocking)
        return flocking.rule_params.heading

    assert heading("f1", {"heading": 90.0}) == 90.0
    assert heading("f1", {"heading": 0.0}) == 0.0
    assert heading("f1", {}) == zlib.crc32(b"f1") % 360
    assert heading("f2", {}) == zlib.crc32(b"f2") % 360 != zlib.crc32(b"f1") % 360
