"""The real PX4 v1.15.4 (SITL with SIH) flown by a whole agent: mission, link cut, a silent behavior,
a pilot, an HLC restart and the battery failsafe.

One vehicle for the module (`px4`), booted with the agent already connected. Each test starts from the
vehicle landed, disarmed and the MC in STANDBY, asserts what the operator sees (MC/HLC states,
``hlc_error_t`` reasons) and what PX4 did by its own telemetry on its GCS link (`harness.Gcs`), and
leaves it landed. docs/px4.md says what each of these does and why.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from tests.conftest import Probe
from tests.netns import NetNamespace
from tests.polling import wait_for
from tests.sitl_arducopter import flight
from tests.sitl_arducopter.flight import (
    command,
    direction,
    errors,
    fly_east,
    hlc_states,
    landed,
    take_off,
    wait_state,
)
from tests.sitl_px4.harness import Px4

pytestmark = [pytest.mark.netns, pytest.mark.timeout(300)]
TIMINGS: dict[str, float] = {}


@pytest.fixture(autouse=True)
def back_on_the_ground(request: pytest.FixtureRequest) -> Iterator[None]:
    """After each test the vehicle is on the ground, disarmed, the MC in STANDBY: a failed test lands it."""
    yield
    flight.back_on_the_ground(
        request.getfixturevalue("px4"), request.getfixturevalue("sitl_probe"), "AUTO.LAND"
    )


@pytest.fixture(scope="module")
def px4(sitl_netns: NetNamespace, sitl_dir: Path) -> Iterator[Px4]:
    vehicle = Px4(sitl_netns, sitl_dir / "px4", nodes=("hlc", "mc", "bma"))
    yield vehicle
    vehicle.stop()


def east_speed(px4: Px4, probe: Probe, seconds: float) -> tuple[float, float, dict[str, Any]]:
    """PX4's own east and north speed (m/s) over `seconds` of the operator's 1 m/s east, from
    LOCAL_POSITION_NED and PX4's clock; and PX4's state at the end."""
    a = px4.state()
    fly_east(px4, probe, seconds, speed=1.0)
    b = px4.state()
    dt = b["time_boot"] - a["time_boot"]
    return (b["y"] - a["y"]) / dt, (b["x"] - a["x"]) / dt, b


def test_boot_take_off_mission_east_at_1_m_s_rtl_landed_standby(px4: Px4, sitl_probe: Probe) -> None:
    """TAKEOFF sent at STANDBY waits for PX4's pre-arm checks; the adapter sets PX4's failsafe
    parameters (configure_vehicle); MISSION east at 1 m/s is flown in OFFBOARD at 1 m/s by PX4's own
    position; RTL is PX4's AUTO.RTL and ends landed, disarmed, the MC in STANDBY."""
    probe = sitl_probe
    wait_state(probe, "mc", M.STANDBY, timeout=90)
    mark = probe.mark()
    sent = time.monotonic()
    command(probe, O.TAKEOFF)
    wait_state(probe, "mc", M.TAKEOFF, timeout=10, since=mark)
    assert wait_for(lambda: px4.state()["armed"], timeout=120, interval=0.2)
    armed = time.monotonic()
    wait_state(probe, "hlc", H.AIRBORNE, timeout=60, since=mark)
    airborne = time.monotonic()
    TIMINGS.update(boot_to_armed=armed - px4.booted_at, takeoff_to_airborne=airborne - sent)
    print(f"\nPX4 SITL timings: {TIMINGS}")
    log = px4.agent.log("hlc")
    for name in ("COM_OBL_RC_ACT", "NAV_DLL_ACT"):
        assert f"vehicle parameter {name} set to" in log, log[-3000:]
    state = px4.state()
    assert state["armed"] and state["alt"] > 4.0 and state["mode"] == "AUTO.LOITER", state
    wait_state(probe, "mc", M.MISSION, timeout=10, since=probe.mark())
    fly_east(px4, probe, 3.0, speed=1.0)  # the OFFBOARD hand-over and the acceleration
    assert px4.state()["mode"] == "OFFBOARD", px4.state()
    ve, vn, moved = east_speed(px4, probe, 5.0)
    print(f"PX4 east {ve:.2f} m/s, north {vn:.2f} m/s (LOCAL_POSITION_NED)")
    assert 0.85 < ve < 1.15 and abs(vn) < 0.2, (ve, vn, moved)
    assert moved["east"] > 4.0, moved  # GLOBAL_POSITION_INT from home agrees
    direction(probe, 0.0, 0.0, active=False)
    mark = probe.mark()
    px4.gcs.ok(op="mark")
    command(probe, O.RTL)
    wait_state(probe, "mc", M.RTL, timeout=10, since=mark)
    wait_state(probe, "hlc", H.RTL, timeout=10, since=mark)
    down = landed(px4, probe, mark)
    modes = [m for _, m in px4.gcs.ok(op="record")["modes"]]
    assert modes[:1] == ["AUTO.RTL"], modes
    assert abs(down["north"]) < 2.0 and abs(down["east"]) < 2.0, down
    assert errors(probe, mark) == []


def test_link_cut_5_s_in_flight_then_restored(px4: Px4, sitl_probe: Probe) -> None:
    """The offboard link cut for 5 s while flying east at 1 m/s: the HLC says LLC_DOWN with the link's
    age; PX4 misses the set-point stream for COM_OF_LOSS_T (1 s), leaves OFFBOARD on its offboard-loss
    failsafe and holds (COM_OBL_RC_ACT = Hold, set by the adapter); when the link is back the HLC names
    the failsafe, and the MC's on_link_regained (RTL) brings the vehicle home."""
    probe = sitl_probe
    take_off(px4, probe)
    mark = probe.mark()
    fly_east(px4, probe, 3.0, speed=1.0)
    assert px4.state()["mode"] == "OFFBOARD", px4.state()
    px4.gcs.ok(op="mark")
    px4.gcs.relay("cut")
    fly_east(px4, probe, 3.0, speed=1.0)  # the operator keeps pointing east: nothing reaches PX4
    late = px4.state()
    fly_east(px4, probe, 2.0, speed=1.0)
    at_restore = px4.state()
    px4.gcs.relay("pass")
    down = wait_state(probe, "hlc", H.LLC_DOWN, timeout=1, since=mark)
    assert "link" in down["reason"].lower(), down
    modes = [m for _, m in px4.gcs.ok(op="record")["modes"]]
    assert modes[:1] == ["AUTO.LOITER"], modes  # PX4's offboard-loss failsafe: Hold
    assert abs(at_restore["east"] - late["east"]) < 0.5, (late, at_restore)  # it stopped by itself
    wait_state(probe, "mc", M.RTL, timeout=15, since=mark)
    assert any("regained" in e for e in errors(probe, mark)), errors(probe, mark)
    print(f"\nHLC states after the cut: {hlc_states(probe, mark)}; errors: {errors(probe, mark)}")
    home = landed(px4, probe, mark)
    assert abs(home["north"]) < 2.0 and abs(home["east"]) < 2.0, home


def test_behavior_going_silent_hovers_in_offboard(px4: Px4, sitl_probe: Probe) -> None:
    """The behavior stops sending (its BMA frozen by SIGSTOP) while PX4 flies its 1 m/s east: the HLC
    hovers after velocity_timeout and the adapter streams zero set-points, so PX4 stops in OFFBOARD --
    no stale set-point is flown on, and PX4's offboard-loss failsafe is not what stops it."""
    probe = sitl_probe
    take_off(px4, probe)
    mark = probe.mark()
    fly_east(px4, probe, 3.0, speed=1.0)
    assert px4.state()["mode"] == "OFFBOARD", px4.state()
    bma = px4.agent.procs["bma"]
    os.killpg(bma.pid, signal.SIGSTOP)
    try:
        fly_east(px4, probe, 3.0, speed=1.0)  # the operator still points east; the behavior is silent
        ve, vn, state = east_speed(px4, probe, 2.0)
    finally:
        os.killpg(bma.pid, signal.SIGCONT)
    assert abs(ve) < 0.15 and abs(vn) < 0.15, (ve, vn, state)
    assert state["mode"] == "OFFBOARD" and state["armed"], state
    assert [s for s, _ in hlc_states(probe, mark)] == [H.AIRBORNE], hlc_states(probe, mark)
    assert "hover: no velocity command for" in px4.agent.log("hlc")
    fly_east(px4, probe, 3.0, speed=1.0)  # the behavior is back: PX4 flies again
    assert px4.state()["vy"] > 0.5, px4.state()
    command(probe, O.LAND)
    landed(px4, probe, mark)


def test_pilot_takeover_from_a_second_ground_station(px4: Px4, sitl_probe: Probe) -> None:
    """A pilot switches PX4 to Hold from another ground station while it flies OFFBOARD: MANUAL, the
    HLC sends nothing more (the operator's direction no longer moves it); the pilot lands, the HLC is
    READY and the MC in STANDBY again."""
    probe = sitl_probe
    take_off(px4, probe)
    mark = probe.mark()
    fly_east(px4, probe, 3.0, speed=1.0)
    assert px4.state()["mode"] == "OFFBOARD", px4.state()
    px4.gcs.ok(op="set_mode", mode="AUTO.LOITER")
    manual = wait_state(probe, "hlc", H.MANUAL, timeout=10, since=mark)
    assert "pilot" in manual["reason"].lower(), manual
    wait_state(probe, "mc", M.MANUAL, timeout=10, since=mark)
    time.sleep(2.0)  # PX4's Hold brakes
    before = px4.state()
    fly_east(px4, probe, 3.0, speed=1.0)
    after = px4.state()
    assert after["mode"] == "AUTO.LOITER" and abs(after["east"] - before["east"]) < 0.5, (before, after)
    px4.gcs.ok(op="set_mode", mode="AUTO.LAND")
    landed(px4, probe, mark)


def test_hlc_restart_in_flight_resyncs_without_arming_or_taking_off(px4: Px4, sitl_probe: Probe) -> None:
    """The HLC killed while PX4 holds after the take-off and started again: it finds the vehicle
    flying in Hold, resyncs to AIRBORNE without arming or taking off, and flies the operator's
    direction (OFFBOARD) again."""
    probe = sitl_probe
    take_off(px4, probe)
    px4.agent.kill("hlc")
    time.sleep(1.0)
    mark = probe.mark()
    px4.start("hlc")
    wait_state(probe, "hlc", H.AIRBORNE, timeout=30, since=mark)
    log = px4.agent.log("hlc")
    assert "INIT -> AIRBORNE" in log and "autopilot ARM" not in log and "autopilot TAKEOFF" not in log
    assert {m["state"] for m in probe.history("copter/MC_STATE", "mc_state_t", since=mark)} <= {
        M.MISSION,
        M.HLC_LOST,
    }
    wait_state(probe, "mc", M.MISSION, timeout=10, since=probe.mark())
    start = px4.state()
    fly_east(px4, probe, 4.0, speed=1.0)  # it still obeys
    assert px4.state()["mode"] == "OFFBOARD" and px4.state()["east"] - start["east"] > 2.0, px4.state()
    command(probe, O.LAND)
    landed(px4, probe, mark)


def test_battery_failsafe_returns_home(px4: Px4, sitl_probe: Probe) -> None:
    """PX4's simulated battery drains in seconds (SIM_BAT_DRAIN, SIM_BAT_MIN_PCT) with its critical
    level raised (BAT_CRIT_THR): PX4 returns (COM_LOW_BAT_ACT = Return, set by the adapter); the
    operator sees the battery and the return; PX4 lands at home. Last in the module: the drained
    battery stays drained."""
    probe = sitl_probe
    take_off(px4, probe)
    mark = probe.mark()
    fly_east(px4, probe, 3.0, speed=1.0)
    px4.gcs.ok(op="mark")
    for name, value in (
        ("BAT_LOW_THR", 0.5),
        ("BAT_CRIT_THR", 0.25),
        ("SIM_BAT_MIN_PCT", 5.0),
        ("SIM_BAT_DRAIN", 10.0),
    ):
        px4.gcs.set_param(name, value)
    deadline = time.monotonic() + 40
    while time.monotonic() < deadline and px4.state()["mode"] == "OFFBOARD":
        direction(probe, 90.0, 1.0)
        time.sleep(0.5)
    record = px4.gcs.ok(op="record")
    print(f"\nbattery: PX4 modes {record['modes']}, texts {[t for _, _, t in record['texts']]}")
    print(f"HLC states {hlc_states(probe, mark)}; errors {errors(probe, mark)}")
    assert "AUTO.RTL" in [m for _, m in record["modes"]], record
    assert any("battery" in r.lower() for _, r in hlc_states(probe, mark)) or any(
        "battery" in e.lower() for e in errors(probe, mark)
    ), (hlc_states(probe, mark), errors(probe, mark))
    home = landed(px4, probe, mark, timeout=150)
    assert abs(home["north"]) < 2.0 and abs(home["east"]) < 2.0, home
