"""auto_operator through a BMA on memq://, with MC states published by the test (a scripted MC)."""

from __future__ import annotations

import time
from typing import Any

from antalate_lcm.msgs import mc_state_t, operator_cmd_t
from antalate_lcm.wire import security
from tests.harness.bma import AGENT, Harness, harness, make_config
from tests.harness.polling import wait_for


def _config(params: dict[str, Any], **extra: Any) -> Any:
    return make_config(
        [{"name": "ops", "behaviors": [{"plugin": "auto_operator", "params": params}]}], **extra
    )


def test_takeoff_in_standby_resent_until_the_mc_moves_on() -> None:
    with harness(_config({"retry": 0.1, "altitude": 12.5})) as h:
        cmds = h.record("OPERATOR_CMD")
        h.bma("ops")
        h.mc_state("STANDBY")
        assert wait_for(lambda: len(cmds) >= 3)  # resent every 0.1 s: a lost datagram is not fatal
        first = cmds[0]
        assert first.command == operator_cmd_t.TAKEOFF and first.target == AGENT and first.altitude == 12.5
        assert first.header.agent == AGENT
        seqs = [c.header.seq for c in cmds]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # a fresh seq per command (the MC acks it)
        h.mc_state("TAKEOFF")
        h.settle()
        n = len(cmds)
        time.sleep(0.3)
        h.settle()
        assert len(cmds) == n  # deactivated: the resending stops


def test_rtl_after_the_mission_time() -> None:
    with harness(_config({"retry": 0.1, "rtl_after": 0.3})) as h:
        cmds = h.record("OPERATOR_CMD")
        h.bma("ops")
        h.mc_state("MISSION")
        t0 = time.monotonic()
        assert wait_for(lambda: cmds)
        assert time.monotonic() - t0 >= 0.25
        assert cmds[0].command == operator_cmd_t.RTL and cmds[0].target == AGENT


def test_no_rtl_without_rtl_after() -> None:
    with harness(_config({"retry": 0.1})) as h:
        cmds = h.record("OPERATOR_CMD")
        node = h.bma("ops")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active) == ["auto_operator"])
        time.sleep(0.3)
        h.settle()
        assert cmds == []


class ScriptedMc:
    """Just enough of an MC: TAKEOFF → MISSION, RTL → LAND → STANDBY, acknowledging by state."""

    def __init__(self, h: Harness) -> None:
        self.h = h
        self.state = "STANDBY"
        self.history = ["STANDBY"]
        self.last_seq = 0
        h.probe.subscribe("OPERATOR_CMD", self.on_cmd)
        h.probe.create_timer(0.05, self.publish)

    def publish(self) -> None:
        msg = mc_state_t()
        msg.state = getattr(mc_state_t, self.state)
        msg.last_command_seq = self.last_seq
        self.h.probe.publish("MC_STATE", msg)

    def go(self, *states: str) -> None:
        for state in states:
            self.state = state
            self.history.append(state)
            self.publish()

    def on_cmd(self, cmd: operator_cmd_t) -> None:
        if cmd.command == operator_cmd_t.TAKEOFF and self.state == "STANDBY":
            self.last_seq = cmd.header.seq
            self.go("TAKEOFF")
            self.h.probe.call_later(0.05, lambda: self.go("MISSION"))
        elif cmd.command == operator_cmd_t.RTL and self.state == "MISSION":
            self.last_seq = cmd.header.seq
            self.go("RTL")
            self.h.probe.call_later(0.05, lambda: self.go("LAND", "STANDBY"))


def test_a_fully_autonomous_sortie_with_no_human() -> None:
    with harness(_config({"retry": 0.5, "rtl_after": 0.2, "max_flights": 2})) as h:
        mc = h.sync(lambda: ScriptedMc(h))
        node = h.bma("ops")
        assert wait_for(lambda: mc.history.count("MISSION") == 2, timeout=5)
        assert wait_for(lambda: mc.history[-1] == "STANDBY", timeout=5)
        time.sleep(0.3)  # max_flights reached: no third takeoff
        assert mc.history == ["STANDBY"] + ["TAKEOFF", "MISSION", "RTL", "LAND", "STANDBY"] * 2
        assert h.sync(lambda: node.behavior("auto_operator")).flights == 2


def test_commands_are_signed_when_a_swarm_key_is_configured() -> None:
    key = "correct horse battery staple"
    with harness(_config({"retry": 0.1}, security={"swarm_key": key})) as h:
        cmds = h.record("OPERATOR_CMD")
        h.bma("ops")
        h.mc_state("STANDBY")
        assert wait_for(lambda: len(cmds) >= 2)
        for cmd in cmds:
            assert cmd.header.mac_len == 32
            assert security.verify(cmd, key, window=5.0) is None
        assert security.verify(cmds[0], "another key", window=5.0) is not None
