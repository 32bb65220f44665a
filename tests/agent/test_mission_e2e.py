"""A whole mission and every failsafe, with the MC and the HLC as separate processes over real UDP
multicast inside a private network namespace (docs/design.md §5, §6, §12)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from tests.conftest import Probe
from tests.harness.agents import AgentProcesses

pytestmark = pytest.mark.netns


def mc(probe: Probe, state: int, agent: str = "alpha", timeout: float = 15, since: int = 0) -> dict[str, Any]:
    msg = probe.wait(f"{agent}/MC_STATE", "mc_state_t", timeout=timeout, since=since, state=state)
    assert msg is not None, f"{agent} MC never reached state {state}"
    return msg


def hlc(
    probe: Probe, state: int, agent: str = "alpha", timeout: float = 15, since: int = 0
) -> dict[str, Any]:
    msg = probe.wait(f"{agent}/HLC_STATE", "hlc_state_t", timeout=timeout, since=since, state=state)
    assert msg is not None, f"{agent} HLC never reached state {state}"
    return msg


def command(
    probe: Probe, cmd: int, seq: int, agent: str = "alpha", channel: str | None = None, **extra: Any
) -> None:
    probe.publish(
        channel or f"{agent}/OPERATOR_CMD",
        "operator_cmd_t",
        header={"seq": seq, "agent": "test-op"},
        command=cmd,
        **extra,
    )


def telemetry(probe: Probe, agent: str = "alpha", since: int = 0, **where: Any) -> dict[str, Any]:
    msg = probe.wait(f"{agent}/TELEMETRY", "telemetry_t", since=since, **where)
    assert msg is not None
    return msg


def test_full_mission(launch: Callable[..., AgentProcesses], probe: Probe) -> None:
    agent = launch()
    mc(probe, M.STANDBY)
    hlc(probe, H.READY)
    command(probe, O.TAKEOFF, seq=7, altitude=4.0)
    assert mc(probe, M.TAKEOFF)["last_command_seq"] == 7
    hlc(probe, H.AIRBORNE)
    mc(probe, M.MISSION)
    # velocity commands move the vehicle only in MISSION; stream them for a second, heading east
    mark = probe.mark()
    for _ in range(10):
        probe.publish("alpha/VELOCITY_CMD", "velocity_cmd_t", frame=1, vx=0.0, vy=3.0)
    moving = probe.wait("alpha/TELEMETRY", "telemetry_t", since=mark, timeout=5, in_air=True)
    assert moving is not None
    t = telemetry(probe, since=mark)
    assert t["alt"] == pytest.approx(4.0, abs=0.5)
    command(probe, O.RTL, seq=8)
    assert mc(probe, M.RTL)["last_command_seq"] == 8
    mc(probe, M.STANDBY, since=probe.mark(), timeout=20)
    hlc(probe, H.READY)
    assert agent.alive("mc") and agent.alive("hlc")
    assert "TAKEOFF -> MISSION" in agent.log("mc")


def test_commands_that_do_not_apply_are_rejected_and_not_acknowledged(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    agent = launch()
    mc(probe, M.STANDBY)
    command(probe, O.LAND, seq=3)  # LAND in STANDBY does not apply
    command(probe, O.TAKEOFF, seq=4, target="someone-else")  # not for us
    probe.raw("alpha/OPERATOR_CMD", b"\x01garbage")  # not a command at all
    mark = probe.mark()
    msg = mc(probe, M.STANDBY, since=mark)
    assert msg["last_command_seq"] == 0
    assert "rejected operator LAND" in agent.log("mc")
    # broadcast commands are heard; a duplicate delivery is idempotent
    command(probe, O.TAKEOFF, seq=5, channel="SWARM/OPERATOR_CMD")
    command(probe, O.TAKEOFF, seq=5, channel="SWARM/OPERATOR_CMD")
    assert mc(probe, M.TAKEOFF)["last_command_seq"] == 5
    mc(probe, M.MISSION)
    assert agent.log("mc").count("STANDBY -> TAKEOFF") == 1
    assert agent.alive("mc")


def test_velocity_failsafes(launch: Callable[..., AgentProcesses], probe: Probe) -> None:
    agent = launch(hlc={"max_horizontal_speed": 2.0, "velocity_timeout": 0.5})
    mc(probe, M.STANDBY)
    # in STANDBY a velocity command must not reach the vehicle
    probe.publish("alpha/VELOCITY_CMD", "velocity_cmd_t", frame=1, vx=3.0)
    command(probe, O.TAKEOFF, seq=1)
    mc(probe, M.MISSION)
    # NaN is rejected, the HLC stays alive
    probe.publish("alpha/VELOCITY_CMD", "velocity_cmd_t", frame=1, vx=math.nan)
    # a too-fast command is clamped to 2 m/s
    mark = probe.mark()
    for _ in range(30):
        probe.publish("alpha/VELOCITY_CMD", "velocity_cmd_t", frame=1, vx=10.0)
    fast = probe.history("alpha/TELEMETRY", "telemetry_t")[-1]
    assert math.hypot(fast["vn"], fast["ve"]) <= 2.05
    # no more commands: after velocity_timeout the vehicle hovers
    stopped = probe.wait("alpha/TELEMETRY", "telemetry_t", since=mark, timeout=8, in_air=True)
    assert stopped is not None
    import time

    time.sleep(3.0)
    last = probe.history("alpha/TELEMETRY", "telemetry_t")[-1]
    assert math.hypot(last["vn"], last["ve"]) < 0.3, last
    log = agent.log("hlc")
    assert "non-finite" in log or "NaN" in log or "nan" in log
    assert "hover" in log
    assert agent.alive("hlc")


def test_arming_refused_returns_to_standby_with_an_error(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    launch(sim={"refuse_arm": True})
    mc(probe, M.STANDBY)
    command(probe, O.TAKEOFF, seq=1)
    mc(probe, M.TAKEOFF)
    err = probe.wait("alpha/HLC_ERROR", "hlc_error_t", timeout=10)
    assert err is not None and err["code"] == 2  # ARM_FAILED
    mc(probe, M.STANDBY, since=probe.mark())


def fails_safe_then_lands(probe: Probe, hlc_state: int, mc_state: int, timeout: float) -> None:
    """After the operator's TAKEOFF the HLC reports ``hlc_state`` (a failsafe) within ``timeout`` s, the
    MC follows to ``mc_state``, and the agent lands back in STANDBY."""
    mc(probe, M.STANDBY)
    command(probe, O.TAKEOFF, seq=1)
    hlc(probe, hlc_state, timeout=timeout)
    mc(probe, mc_state)
    mc(probe, M.STANDBY, since=probe.mark(), timeout=20)


def test_low_battery_returns_home(launch: Callable[..., AgentProcesses], probe: Probe) -> None:
    launch(sim={"battery": 23.0, "drain_flying": 90.0}, hlc={"low_battery": 20.0})
    fails_safe_then_lands(probe, H.LOW_BATTERY, M.RTL, timeout=20)


def test_takeoff_refused_at_low_battery(launch: Callable[..., AgentProcesses], probe: Probe) -> None:
    launch(sim={"battery": 15.0})
    mc(probe, M.STANDBY)
    command(probe, O.TAKEOFF, seq=1)
    err = probe.wait("alpha/HLC_ERROR", "hlc_error_t", timeout=10)
    assert err is not None and "battery" in err["text"].lower()
    mc(probe, M.STANDBY, since=probe.mark())


def test_altitude_not_gained_lands(launch: Callable[..., AgentProcesses], probe: Probe) -> None:
    launch(sim={"climb_rate": 0.3}, hlc={"gain_altitude_timeout": 1.5})
    fails_safe_then_lands(probe, H.LANDING, M.LAND, timeout=10)


def test_link_lost_for_good_rejects_commands_nobody_can_execute(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    """The link never comes back (tests/safety/test_failsafes_e2e.py has it coming back): ERROR, and an RTL
    is rejected with the reason while the HLC reports LLC_DOWN (the vehicle is on its own failsafe)."""
    agent = launch(sim={"link_loss_after": 1.5}, hlc={"link_timeout": 1.0})
    mc(probe, M.STANDBY)
    command(probe, O.TAKEOFF, seq=1)
    hlc(probe, H.LLC_DOWN, timeout=15)
    mc(probe, M.ERROR)
    command(probe, O.RTL, seq=2)
    mark = probe.mark()
    assert mc(probe, M.ERROR, since=mark)["last_command_seq"] == 1
    assert "the autopilot cannot be reached" in agent.log("mc")
    assert agent.alive("mc") and agent.alive("hlc")


def test_pilot_takeover_then_landing(launch: Callable[..., AgentProcesses], probe: Probe) -> None:
    launch(sim={"takeover_after": 1.5, "takeover_land_delay": 1.0})
    fails_safe_then_lands(probe, H.MANUAL, M.MANUAL, timeout=15)


def restarted_in_flight(agent: AgentProcesses, probe: Probe, node: str) -> int:
    """The agent flies its mission, ``node`` is killed (no goodbye) and started again: the probe's
    mark just before the restart."""
    mc(probe, M.STANDBY)
    command(probe, O.TAKEOFF, seq=1)
    mc(probe, M.MISSION)
    agent.kill(node)
    mark = probe.mark()
    agent.start(node)
    return mark


def test_mc_restart_mid_flight_resyncs_without_commands(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    agent = launch()
    mark = restarted_in_flight(agent, probe, "mc")
    mc(probe, M.MISSION, since=mark)
    # the HLC never left AIRBORNE: the restart sent nothing
    states = {m["state"] for m in probe.history("alpha/HLC_STATE", "hlc_state_t", since=mark)}
    assert states == {H.AIRBORNE}
    assert "INIT -> MISSION" in agent.log("mc")
    command(probe, O.LAND, seq=2)
    mc(probe, M.STANDBY, since=probe.mark(), timeout=20)


def test_hlc_restart_mid_flight_resyncs_without_commands(
    launch: Callable[..., AgentProcesses], probe: Probe, tmp_path: Path
) -> None:
    agent = launch(sim={"state_file": str(tmp_path / "vehicle.json")})
    mark = restarted_in_flight(agent, probe, "hlc")
    hlc(probe, H.AIRBORNE, since=mark)
    log = agent.log("hlc")
    assert "INIT -> AIRBORNE" in log
    assert "autopilot ARM" not in log and "autopilot TAKEOFF" not in log
    assert {m["state"] for m in probe.history("alpha/MC_STATE", "mc_state_t", since=mark)} == {M.MISSION}
    command(probe, O.RTL, seq=2)
    mc(probe, M.STANDBY, since=probe.mark(), timeout=20)
