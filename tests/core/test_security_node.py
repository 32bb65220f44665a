"""Authentication and validation in the node layer, with real MC, HLC, BMA and sim vehicle on memq://.

Each attack of issue 13 (bus part) is sent the way an attacker would: raw datagrams on the agent's
channels, unsigned, forged, from the wrong sender or replayed. Each test first waits until the node
has counted the rejection (so the message was processed), then checks that nothing moved, and where
it matters shows the same path does move the vehicle for a genuine message (the test can fail).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.agent.bma import BmaNode
from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.agent.mc.node import McNode
from antalate_lcm.core.admission import INSECURE_REMINDER
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, InsecureBus, Node, NodeSettings
from antalate_lcm.msgs import (
    direction_cmd_t,
    hlc_state_t,
    mc_state_t,
    operator_cmd_t,
    payload_t,
    velocity_cmd_t,
)
from antalate_lcm.wire.security import Reason, sign
from antalate_lcm.wire.vocabulary import HlcState, McState
from tests.harness.agents import FAST_SIM
from tests.harness.inprocess import InProcess
from tests.harness.polling import wait_for

KEY = "node-test-swarm-key"
AGENT = "alpha"
SWARM_BMA = {
    "name": "swarm",
    "behaviors": [
        {
            "plugin": "dovrat_swarm",
            "activate_on": ["MISSION"],
            "tick_hz": 20.0,
            "params": {"forward_speed": 1.0, "detection_source": "payload"},
        }
    ],
}


def config(key: str = KEY, **extra: Any) -> Config:
    doc: dict[str, Any] = {
        "agent": {"name": AGENT},
        "buses": {"lan": "memq://"},
        "hlc": {"autopilot": "sim", "default_takeoff_altitude": 2.0, "autopilot_params": FAST_SIM},
        "security": {"swarm_key": key, **extra.pop("security", {})},
        **extra,
    }
    return parse_config(doc, "test.toml")


class Swarm(InProcess):
    """A started context; nodes added by the test; an operator console node and an attacker."""

    def __init__(self, cfg: Config) -> None:
        super().__init__(cfg)
        self.cfg = cfg
        self.operator = self.add(
            Node(NodeSettings.from_config(cfg, agent="console"), self.context, name="console")
        )

    def stop(self, node: Node) -> None:
        node.stop()
        self.nodes.remove(node)

    def send(
        self, channel: str, msg: Any, *, agent: str = AGENT, key: str = "", utime: float | None = None
    ) -> bytes:
        """What an attacker puts on the wire: any header, signed with ``key`` if given."""
        msg.header.utime = int((time.time() if utime is None else utime) * 1e6)
        msg.header.agent, msg.header.seq = agent, 4242
        if key:
            sign(msg, key)
        data: bytes = msg.encode()
        self.context.buses.publish("lan", channel, data)
        return data

    def raw(self, channel: str, data: bytes) -> None:
        self.context.buses.publish("lan", channel, data)

    def capture(self, channel: str) -> list[bytes]:
        got: list[bytes] = []
        self.context.buses.subscribe("lan", channel, None, lambda _ch, data: got.append(data))
        return got

    def command(self, name: str, seq: int, target: str = AGENT) -> None:
        msg = operator_cmd_t()
        msg.command, msg.target = getattr(operator_cmd_t, name), target
        self.operator.publish("OPERATOR_CMD", msg, seq=seq, agent=target)


def swarm(cfg: Config) -> Swarm:
    """``with swarm(cfg) as s``: closed at the end of the block."""
    return Swarm(cfg)


def rejected(node: Node, reason: Reason) -> Callable[[], int]:
    auth = node.admission
    return lambda: auth.authenticator.rejected.get(reason, 0) if auth.authenticator else 0


def ready(s: Swarm) -> tuple[HlcNode, McNode]:
    hlc = s.add(HlcNode(s.cfg, s.context))
    mc = s.add(McNode(s.cfg, s.context))
    assert wait_for(lambda: mc.state is McState.STANDBY and hlc.state is HlcState.READY, 10)
    return hlc, mc


def fly(s: Swarm) -> tuple[HlcNode, McNode]:
    hlc, mc = ready(s)
    s.command("TAKEOFF", 1)
    assert wait_for(lambda: mc.state is McState.MISSION and hlc.state is HlcState.AIRBORNE, 15)
    return hlc, mc


def _mc_state(state: int) -> mc_state_t:
    msg = mc_state_t()
    msg.state = state
    return msg


# ---------------------------------------------------------------------------------------------- spoofs
def test_spoofed_mc_state_takeoff_launches_nothing() -> None:
    with swarm(config()) as s:
        hlc, _ = ready(s)
        s.send(f"{AGENT}/MC_STATE", _mc_state(mc_state_t.TAKEOFF))  # unsigned
        s.send(f"{AGENT}/MC_STATE", _mc_state(mc_state_t.TAKEOFF), key="guessed-key")  # forged
        assert wait_for(lambda: rejected(hlc, Reason.UNSIGNED)() and rejected(hlc, Reason.FORGED)(), 5)
        sim = hlc.adapter.state()
        assert hlc.state is HlcState.READY and not sim.armed and sim.alt == 0.0
        # the same message, genuinely signed by the MC's agent, is obeyed: the path is live
        s.send(f"{AGENT}/MC_STATE", _mc_state(mc_state_t.TAKEOFF), key=KEY)
        assert wait_for(lambda: hlc.state is not HlcState.READY, 5)


def test_spoofed_hlc_state_llc_down_does_not_ground_the_mc() -> None:
    with swarm(config()) as s:
        _, mc = ready(s)
        down = hlc_state_t()
        down.state = hlc_state_t.LLC_DOWN
        s.send(f"{AGENT}/HLC_STATE", down)
        s.send(f"{AGENT}/HLC_STATE", down, key="guessed-key")
        # a peer with the swarm key cannot speak for another agent's HLC either
        s.send(f"{AGENT}/HLC_STATE", down, key=KEY, agent="beta")
        assert wait_for(
            lambda: (
                rejected(mc, Reason.UNSIGNED)()
                and rejected(mc, Reason.FORGED)()
                and rejected(mc, Reason.WRONG_SENDER)()
            ),
            5,
        )
        assert mc.state is McState.STANDBY


def test_injected_and_replayed_velocity_commands_fly_nowhere() -> None:
    with swarm(config()) as s:
        hlc, _ = fly(s)
        wire = s.capture(f"{AGENT}/VELOCITY_CMD")
        behavior = s.add(
            Node(NodeSettings.from_config(s.cfg), s.context, name="behavior")
        )  # the agent's own publisher of velocity
        hover = velocity_cmd_t()
        hover.frame = velocity_cmd_t.NED
        behavior.publish("VELOCITY_CMD", hover)
        assert wait_for(lambda: wire, 5)
        north = velocity_cmd_t()
        north.frame, north.vx = velocity_cmd_t.NED, 3.2
        for _ in range(10):
            s.send(f"{AGENT}/VELOCITY_CMD", north)
        s.send(f"{AGENT}/VELOCITY_CMD", north, key=KEY, agent="beta")
        s.raw(f"{AGENT}/VELOCITY_CMD", wire[0])  # a genuine hover, replayed: no effect, but counted
        assert wait_for(
            lambda: (
                rejected(hlc, Reason.UNSIGNED)() == 10
                and rejected(hlc, Reason.WRONG_SENDER)()
                and rejected(hlc, Reason.REPLAYED)()
            ),
            5,
        )
        assert abs(hlc.adapter.state().vn) < 0.5
        # the agent's own signed command is flown: the check above could have failed
        north_ok = velocity_cmd_t()
        north_ok.frame, north_ok.vx = velocity_cmd_t.NED, 1.0
        assert wait_for(
            lambda: behavior.publish("VELOCITY_CMD", north_ok) and hlc.adapter.state().vn > 0.5, 5
        )


# ---------------------------------------------------------------------------------------------- replays
def test_a_command_accepted_before_an_mc_restart_is_rejected_after_it(tmp_path: Path) -> None:
    # a long window: only the replay memory may stop the replay, not its age on a slow machine
    cfg = config(security={"state_dir": str(tmp_path), "window": 60.0})
    with swarm(cfg) as s:
        hlc, mc = ready(s)
        wire = s.capture(f"{AGENT}/OPERATOR_CMD")
        s.command("TAKEOFF", 1)
        assert wait_for(lambda: mc.state is McState.MISSION, 15)
        s.command("LAND", 2)
        assert wait_for(lambda: mc.state is McState.STANDBY and hlc.state is HlcState.READY, 20)
        takeoff = wire[0]
        s.stop(mc)
        mc2 = s.add(McNode(cfg, s.context))
        assert wait_for(lambda: mc2.state is McState.STANDBY, 5)
        s.raw(f"{AGENT}/OPERATOR_CMD", takeoff)  # within the window: only the replay memory stops it
        assert wait_for(rejected(mc2, Reason.REPLAYED), 5)
        assert mc2.state is McState.STANDBY and mc2.machine.last_command_seq == 0
        assert (tmp_path / f"{AGENT}.mc.replay.json").exists()
        # an MC without that memory (another state_dir) would have taken off: the test can fail
        fresh = config(security={"state_dir": str(tmp_path / "elsewhere"), "window": 60.0})
        s.stop(mc2)
        mc3 = s.add(McNode(fresh, s.context))
        assert wait_for(lambda: mc3.state is McState.STANDBY, 5)
        s.raw(f"{AGENT}/OPERATOR_CMD", takeoff)
        assert wait_for(lambda: mc3.machine.last_command_seq == 1, 5)


def _direction(azimuth: float, speed: float) -> direction_cmd_t:
    msg = direction_cmd_t()
    msg.active, msg.azimuth, msg.speed = True, azimuth, speed
    return msg


def test_an_older_direction_replayed_within_the_window_is_rejected() -> None:
    with swarm(config(bma=[SWARM_BMA])) as s:
        bma = s.add(BmaNode(s.cfg, s.context, s.cfg.bma[0]))
        behavior: Any = bma.behavior("dovrat_swarm")  # the plugin class, with its own attributes
        wire = s.capture("SWARM/DIRECTION_CMD")
        s.operator.publish("SWARM_DIRECTION_CMD", _direction(90.0, 1.0))
        s.operator.publish("SWARM_DIRECTION_CMD", _direction(270.0, 1.0))
        assert wait_for(
            lambda: len(wire) == 2 and behavior.direction and behavior.direction.azimuth == 270.0, 5
        )
        s.raw("SWARM/DIRECTION_CMD", wire[0])  # the older one, 90 deg, still inside the 5 s window
        assert wait_for(rejected(bma, Reason.REPLAYED), 5)
        assert behavior.direction.azimuth == 270.0


# ---------------------------------------------------------------------------------------------- validation
def test_infinite_and_nan_inputs_are_rejected_and_the_behavior_lives_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with swarm(config(bma=[SWARM_BMA])) as s:
        bma = s.add(BmaNode(s.cfg, s.context, s.cfg.bma[0]))
        behavior: Any = bma.behavior("dovrat_swarm")  # the plugin class, with its own attributes
        got: list[velocity_cmd_t] = []
        s.operator.subscribe("VELOCITY_CMD", got.append, agent=AGENT)
        mc_stand_in = s.add(
            Node(NodeSettings.from_config(s.cfg), s.context, name="mc")
        )  # the agent's MC says MISSION
        mc_stand_in.publish("MC_STATE", _mc_state(mc_state_t.MISSION))
        assert wait_for(lambda: bma.active() == ["dovrat_swarm"], 5)
        payload = payload_t()
        payload.content_type = "application/json"
        payload.data = b'{"detected": true, "count": Infinity}'
        payload.size = len(payload.data)
        s.operator.publish("OPERATOR_PAYLOAD", payload, agent=AGENT)
        s.operator.publish("SWARM_DIRECTION_CMD", _direction(math.inf, 1.0))
        s.operator.publish("SWARM_DIRECTION_CMD", _direction(45.0, math.nan))
        assert wait_for(
            lambda: bma.admission.invalid == 3, 5
        )  # signed nonsense: authentic, and still refused
        assert bma.failures() == {} and bma.active() == ["dovrat_swarm"]
        assert behavior.direction is None
        n = len(got)
        assert wait_for(lambda: len(got) > n + 3, 5)  # still flying its rule
        assert all(math.isfinite(m.vx) and math.isfinite(m.yaw_rate) for m in got)
        assert "azimuth is inf" in caplog.text and "Infinity is not JSON" in caplog.text


def test_unsigned_nonsense_without_a_key_is_refused_too() -> None:
    with swarm(config(key="", bma=[SWARM_BMA])) as s:
        bma = s.add(BmaNode(s.cfg, s.context, s.cfg.bma[0]))
        s.send("SWARM/DIRECTION_CMD", _direction(math.inf, 1.0), agent="anyone")
        cmd = operator_cmd_t()
        cmd.command, cmd.altitude = operator_cmd_t.TAKEOFF, math.inf
        hlc, mc = ready(s)
        s.send("SWARM/OPERATOR_CMD", cmd, agent="anyone")
        assert wait_for(lambda: bma.admission.invalid == 1 and mc.admission.invalid == 1, 5)
        assert mc.state is McState.STANDBY and hlc.state is HlcState.READY


def test_rejected_commands_are_logged_at_a_limited_rate(caplog: pytest.LogCaptureFixture) -> None:
    with swarm(config()) as s:
        _, mc = ready(s)
        caplog.set_level(logging.WARNING, logger=mc.log.name)
        for seq in range(10, 60):
            s.command("LAND", seq)  # well-formed, signed, and not applicable in STANDBY
        s.command("TAKEOFF", 100)  # processed after the fifty
        assert wait_for(lambda: mc.machine.last_command_seq == 100, 5)
        lines = [r for r in caplog.records if "rejected operator LAND" in r.getMessage()]
        assert len(lines) == 1


# ---------------------------------------------------------------------------------------------- exposure
def _udpm_config(**security: Any) -> Config:
    return parse_config(
        {"agent": {"name": AGENT}, "buses": {"lan": "udpm://239.255.76.67:7667?ttl=0"}, "security": security},
        "agent.toml",
    )


def test_a_node_refuses_internal_topics_on_a_network_bus_without_a_key() -> None:
    cfg = _udpm_config()
    context = Context(Buses(cfg.buses), Executor())  # never opened: the refusal comes before any socket
    try:
        with pytest.raises(InsecureBus) as info:
            McNode(cfg, context).start()
    finally:
        context.close()
    text = str(info.value)
    assert "HLC_STATE" in text and "'lan'" in text and "swarm_key" in text and "antalate agent" in text
    assert "insecure = true" in text and "\n" not in text


def test_insecure_true_starts_and_says_so(caplog: pytest.LogCaptureFixture) -> None:
    cfg = _udpm_config(insecure=True)
    context = Context(Buses(cfg.buses), Executor())  # never opened: no socket outside a namespace
    try:
        node = McNode(cfg, context)
        with caplog.at_level(logging.WARNING):
            node.admission.check_exposure("HLC_STATE", "lan")  # what subscribe() runs first
            node.admission.check_exposure("VELOCITY_CMD", "lan")
        assert "INSECURE" in caplog.text and "HLC_STATE on 'lan'" in caplog.text
        assert "launch it" in caplog.text
        # Said once at once, then reminded on the node's timers: one reminder for all its inputs.
        assert caplog.text.count("INSECURE") == 1
        reminders = [t for t in node._timers if t.fn == node.admission.warn_insecure]
        assert [t.period for t in reminders] == [INSECURE_REMINDER]
        with pytest.raises(InsecureBus):
            McNode(_udpm_config(), context).admission.check_exposure("HLC_STATE", "lan")
    finally:
        context.close()


def test_an_open_command_bus_is_said_once_per_process_and_bus(caplog: pytest.LogCaptureFixture) -> None:
    """A thousand keyless agents in one process give one warning, not a thousand; another process
    (another context) and another bus still get theirs."""

    def keyless(name: str) -> Config:
        return parse_config(
            {
                "agent": {"name": name},
                "buses": {"lan": "udpm://239.255.76.67:7667?ttl=0", "wan": "udpm://239.255.76.70:7670?ttl=1"},
            },
            "agent.toml",
        )

    first = Context.in_process(keyless("a-0").buses)  # never opened: no socket outside a namespace
    second = Context.in_process(keyless("b-0").buses)
    try:
        with caplog.at_level(logging.DEBUG):
            for i in range(5):
                mc = McNode(keyless(f"a-{i}"), first)
                mc.admission.check_exposure("OPERATOR_CMD", "lan")
                mc.admission.check_exposure("SWARM_OPERATOR_CMD", "lan")
            McNode(keyless("a-9"), first).admission.check_exposure("OPERATOR_CMD", "wan")
            McNode(keyless("b-0"), second).admission.check_exposure("OPERATOR_CMD", "lan")
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 3, warnings
        assert "bus 'lan'" in warnings[0] and "command a-0, and every other agent" in warnings[0]
        assert "bus 'wan'" in warnings[1] and "a-9" in warnings[1]
        assert "bus 'lan'" in warnings[2] and "b-0" in warnings[2]
        quiet = [
            r.getMessage()
            for r in caplog.records
            if r.levelno == logging.DEBUG and "swarm_key" in r.getMessage()
        ]
        assert [m.rsplit(" ", 1)[1] for m in quiet] == ["a-1", "a-2", "a-3", "a-4"]
    finally:
        first.close()
        second.close()


def test_in_process_context_keeps_internal_topics_off_the_network_bus() -> None:
    cfg = _udpm_config()
    context = Context.in_process(cfg.buses)
    try:
        routes = Node(NodeSettings.from_config(cfg), context, name="probe").routes
        assert routes.subscribe_bus("HLC_STATE") == "_inproc"
        assert routes.subscribe_bus("OPERATOR_CMD") == "lan"
        assert routes.publish_buses("MC_STATE") == ["_inproc", "lan"]  # the operator still sees it
        assert routes.publish_buses("SWARM_OPERATOR_CMD") == ["lan"]
    finally:
        context.close()


def test_payload_json_reaches_the_behavior_when_it_is_right() -> None:
    with swarm(config(bma=[SWARM_BMA])) as s:
        bma = s.add(BmaNode(s.cfg, s.context, s.cfg.bma[0]))
        behavior: Any = bma.behavior("dovrat_swarm")  # the plugin class, with its own attributes
        payload = payload_t()
        payload.content_type = "application/json"
        payload.data = json.dumps({"detected": True, "count": 2}).encode()
        payload.size = len(payload.data)
        s.operator.publish("OPERATOR_PAYLOAD", payload, agent=AGENT)
        assert wait_for(
            lambda: s.context.executor.run_sync(lambda: behavior.detections.detected(behavior.ctx.now)), 5
        )


def test_a_rotation_accepts_the_previous_key_only_while_it_is_listed() -> None:
    old, new = "swarm-key-2025", "swarm-key-2026"
    with swarm(config(key=new, security={"previous_keys": [old]})) as s:
        _, mc = ready(s)
        cmd = operator_cmd_t()
        cmd.command = operator_cmd_t.TAKEOFF
        s.send(f"{AGENT}/OPERATOR_CMD", cmd, agent="console-on-the-old-key", key=old)
        assert wait_for(lambda: mc.machine.last_command_seq == 4242, 5)  # a console not yet rotated
    with swarm(config(key=new)) as s:  # rotation finished: the old key is out of service
        _, mc = ready(s)
        cmd = operator_cmd_t()
        cmd.command = operator_cmd_t.TAKEOFF
        s.send(f"{AGENT}/OPERATOR_CMD", cmd, agent="console-on-the-old-key", key=old)
        assert wait_for(rejected(mc, Reason.FORGED), 5)
        assert mc.machine.last_command_seq == 0 and mc.state is McState.STANDBY
