"""The failsafes of issue 12 end to end: the MC and the HLC as separate processes over real UDP multicast
in a private network namespace, the sim's fault knobs standing in for the field (docs/failsafes.md).

* the autopilot link cut for 5 s in flight, then back: home and STANDBY with no operator action
  (``on_link_regained = "rtl"``, the default); with ``"hold"`` the vehicle stops until the operator's LAND;
* an autopilot failsafe (RTL for a fence breach) is followed, never taken for a pilot, and the operator
  can still LAND;
* the HLC process SIGKILLed in flight: MC HLC_LOST, commands rejected, resync when a new HLC starts;
* an adapter whose ``state()`` raises for a while: LLC_DOWN with the exception, one log line, recovery.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from tests.agent.test_mission_e2e import command, hlc, mc
from tests.conftest import Probe
from tests.harness.agents import AgentProcesses

pytestmark = pytest.mark.netns

LINK_REGAINED = 13  # ErrorCode.LINK_REGAINED
AUTOPILOT_FAILSAFE = 12  # ErrorCode.AUTOPILOT_FAILSAFE


def take_off(probe: Probe, seq: int = 1) -> int:
    """The operator's TAKEOFF, once the MC is in STANDBY, until the mission: the probe's mark then."""
    mc(probe, M.STANDBY)
    command(probe, O.TAKEOFF, seq=seq)
    mc(probe, M.MISSION)
    return probe.mark()


def states(probe: Probe, topic: str, since: int = 0) -> list[int]:
    kind = "mc_state_t" if topic == "MC_STATE" else "hlc_state_t"
    seen = [m["state"] for m in probe.history(f"alpha/{topic}", kind, since=since)]
    return [s for i, s in enumerate(seen) if i == 0 or s != seen[i - 1]]


def in_order(seen: list[int], expected: list[int]) -> bool:
    """`expected` is a subsequence of `seen`."""
    it = iter(seen)
    return all(any(s == e for s in it) for e in expected)


def test_link_cut_for_5s_in_flight_comes_home_with_no_operator_action(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    agent = launch(sim={"link_loss_after": 1.0, "link_loss_for": 5.0}, hlc={"link_timeout": 1.0})
    mark = take_off(probe)
    hlc(probe, H.LLC_DOWN, since=mark)
    assert "autopilot link" in mc(probe, M.ERROR, since=mark)["reason"]
    regained = mc(probe, M.RTL, since=mark, timeout=20)
    assert "on_link_regained = rtl" in regained["reason"]
    assert regained["last_command_seq"] == 1  # nobody asked: nothing acknowledged
    err = probe.wait("alpha/HLC_ERROR", "hlc_error_t", since=mark, code=LINK_REGAINED)
    assert err is not None and "GUIDED" in err["text"]
    mc(probe, M.STANDBY, since=mark, timeout=30)
    hlc(probe, H.READY, since=mark)
    assert in_order(states(probe, "HLC_STATE", since=mark), [H.LLC_DOWN, H.HOLD, H.RTL, H.READY])
    assert in_order(states(probe, "MC_STATE", since=mark), [M.ERROR, M.RTL, M.STANDBY])
    assert M.MANUAL not in states(probe, "MC_STATE", since=mark)
    assert "LLC_DOWN -> HOLD" in agent.log("hlc") and "ERROR -> RTL" in agent.log("mc")
    assert agent.alive("mc") and agent.alive("hlc")


def test_link_regained_with_policy_hold_waits_for_the_operators_land(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    launch(
        sim={"link_loss_after": 1.0, "link_loss_for": 2.0},
        hlc={"link_timeout": 1.0},
        mc={"on_link_regained": "hold"},
    )
    mark = take_off(probe)
    mc(probe, M.ERROR, since=mark)
    held = mc(probe, M.HOLD, since=mark, timeout=20)
    assert "on_link_regained = hold" in held["reason"]
    hlc(probe, H.HOLD, since=mark)
    # It waits: still in the air and still HOLD a while later.
    later = probe.mark()
    assert probe.wait("alpha/TELEMETRY", "telemetry_t", since=later, in_air=True) is not None
    assert probe.wait("alpha/MC_STATE", "mc_state_t", since=later, timeout=1.5, state=M.RTL) is None
    assert mc(probe, M.HOLD, since=later)["last_command_seq"] == 1
    command(probe, O.LAND, seq=2)
    assert mc(probe, M.LAND, since=later)["last_command_seq"] == 2
    mc(probe, M.STANDBY, since=later, timeout=20)


def test_autopilot_failsafe_is_followed_not_taken_for_a_pilot(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    # rtl_altitude: the RTL climbs first, so it is still flying when the operator's LAND comes.
    launch(
        sim={
            "failsafe_after": 1.0,
            "failsafe_mode": "rtl",
            "failsafe_reason": "fence breach",
            "rtl_altitude": 20.0,
        }
    )
    mark = take_off(probe)
    returning = mc(probe, M.RTL, since=mark)
    assert "on its own" in returning["reason"]
    hlc_rtl = hlc(probe, H.RTL, since=mark)
    assert "fence breach" in hlc_rtl["reason"]
    err = probe.wait("alpha/HLC_ERROR", "hlc_error_t", since=mark, code=AUTOPILOT_FAILSAFE)
    assert err is not None and "fence breach" in err["text"] and err["severity"] == 1  # WARNING
    command(probe, O.LAND, seq=2)
    assert mc(probe, M.LAND, since=mark)["last_command_seq"] == 2
    hlc(probe, H.LANDING, since=mark)
    mc(probe, M.STANDBY, since=mark, timeout=30)
    assert M.MANUAL not in states(probe, "MC_STATE", since=mark)
    assert H.MANUAL not in states(probe, "HLC_STATE", since=mark)


def test_hlc_killed_in_flight_mc_reports_hlc_lost_then_resyncs(
    launch: Callable[..., AgentProcesses], probe: Probe, tmp_path: Path
) -> None:
    agent = launch(sim={"state_file": str(tmp_path / "vehicle.json")}, mc={"hlc_timeout": 2.0})
    take_off(probe)
    agent.kill("hlc")  # SIGKILL: no goodbye
    mark = probe.mark()
    lost = mc(probe, M.HLC_LOST, since=mark, timeout=10)
    assert "HLC silent for" in lost["reason"] and "GCS failsafe" in lost["reason"]
    silent_for = float(lost["reason"].split("HLC silent for ")[1].split(" s")[0])
    assert silent_for >= 2.0  # never before hlc_timeout (the deadline above bounds it from above)
    command(probe, O.RTL, seq=2)
    after = probe.mark()
    assert mc(probe, M.HLC_LOST, since=after)["last_command_seq"] == 1  # rejected: nobody can execute it
    assert "nobody can execute it" in agent.log("mc")
    agent.start("hlc")
    hlc(probe, H.AIRBORNE, since=after)
    assert "restart resync" in mc(probe, M.MISSION, since=after)["reason"]
    assert "autopilot ARM" not in agent.log("hlc")
    command(probe, O.RTL, seq=3)
    mc(probe, M.STANDBY, since=probe.mark(), timeout=20)


def test_state_raising_goes_llc_down_then_recovers(
    launch: Callable[..., AgentProcesses], probe: Probe
) -> None:
    agent = launch(sim={"state_error_after": 1.0, "state_error_for": 3.0}, hlc={"link_timeout": 1.0})
    mark = take_off(probe)
    down = hlc(probe, H.LLC_DOWN, since=mark)
    assert "simulated adapter fault" in down["reason"]
    mc(probe, M.ERROR, since=mark)
    mc(probe, M.RTL, since=mark, timeout=20)  # state() works again: the default policy brings it home
    mc(probe, M.STANDBY, since=mark, timeout=30)
    log = agent.log("hlc")
    fault_lines = [line for line in log.splitlines() if "state() raised" in line and "LINK_LOST" not in line]
    assert len(fault_lines) == 1, log  # one rate-limited line, not one per tick (the loop runs at 20 Hz)
    assert "Traceback" not in log
    assert "state() works again" in log
    assert agent.alive("hlc")
