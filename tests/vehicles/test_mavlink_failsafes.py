"""ArduCopter's own failsafes and a cut link, seen through `MavlinkAdapter` (the real pymavlink, 127.0.0.1).

Each test gives the emulated copter the parameters a real one would have (FENCE_*, BATT_*, FS_GCS_*,
GUID_TIMEOUT) and checks what the adapter tells the HLC: a failsafe named and still computer control,
never a pilot; a battery warning from the voltage; no stale set-point flown after a link cut.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import pytest

from antalate_lcm.vehicles import FlightMode, Frame
from antalate_lcm.vehicles.mavlink import MavlinkAdapter
from tests.emulators.mavlink_vehicle import MavlinkVehicle
from tests.harness.polling import wait_for
from tests.vehicles.test_mavlink_adapter import FAST, fly, make_ap, state_until, vehicle_until


def started(params: dict[str, float] | None = None, **kw: Any) -> MavlinkVehicle:
    return MavlinkVehicle("127.0.0.1", 0, 0, **{**FAST, "params": params or {}, **kw}).start()


def pair(
    made: list[Any],
    params: dict[str, float] | None = None,
    vehicle: dict[str, Any] | None = None,
    tcp: bool = False,
    **ap_params: Any,
) -> tuple[MavlinkVehicle, MavlinkAdapter]:
    v = started(params, **(vehicle or {}))
    made.append(v)
    # FS_GCS_TIMEOUT is 1 s in some of these (the firmware's least is 2 s; shorter tests): at the
    # adapter's default 1 Hz a heartbeat late by a loaded machine tripped it before the test cut them
    ap = make_ap(v.tcp_url if tcp else v.udp_url, **{"heartbeat_hz": 4.0, **ap_params})
    made.append(ap)
    ap.connect()
    return v, ap


class Commander:
    """An HLC that keeps sending one velocity at 10 Hz (from its own thread) until stopped."""

    def __init__(self, ap: MavlinkAdapter, vx: float, vy: float) -> None:
        self.ap, self.v = ap, (vx, vy)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.1):
            self.ap.set_velocity(self.v[0], self.v[1], 0.0, 0.0, Frame.NED)

    def halt(self) -> None:
        self.stop.set()
        self.thread.join(2)


# -- a cut TCP link that buffers and then flushes ------------------------------------------------------


@pytest.mark.parametrize("stale", [0.5])
def test_cut_link_backlog_does_not_fly_the_vehicle(made: list[Any], stale: float) -> None:
    """The field trial: during a cut the HLC keeps commanding; the link keeps every byte and flushes it."""
    speed, setpoint_timeout = 2.0, 1.0
    v, ap = pair(
        made,
        vehicle={"guided_timeout": 1.0},
        tcp=True,
        link_stale_after=stale,
        setpoint_timeout=setpoint_timeout,
    )
    fly(ap, v, alt=1.5)
    hlc = Commander(ap, speed, 0.0)
    vehicle_until(v, lambda s: s.vn > speed * 0.9, 2)
    v.cut_link()
    cut = time.monotonic()
    # the vehicle flies its last target for GUID_TIMEOUT, then stops by itself
    vehicle_until(v, lambda s: s.guided_submode == "hover" and abs(s.vn) < 0.05, 3)
    assert wait_for(lambda: ap.state().link_age > 1.0, 2)
    hlc.halt()  # the HLC gives up (LLC_DOWN) while the link is still cut
    assert ap.setpoints_withheld > 0  # it kept trying: the adapter withheld them
    before = v.snapshot()
    restore = time.monotonic()
    v.restore_link()
    state_until(ap, lambda s: s.link_age < 0.5, 3)
    time.sleep(1.5)  # longer than both the set-point timeout and GUID_TIMEOUT
    after = v.snapshot()
    moved = math.hypot(after.north - before.north, after.east - before.east)
    # what reached the vehicle from the backlog: only what was written before the adapter saw the
    # link stale, and a stop right behind it
    flushed = [r for r in v.received_of("SET_POSITION_TARGET_LOCAL_NED") if r.t >= restore]
    assert flushed and flushed[-1].fields["vx"] == 0.0, [r.fields["vx"] for r in flushed]
    assert len([r for r in flushed if r.fields["vx"] == speed]) <= (stale + 0.2) * (10 + 4), len(flushed)
    assert moved < speed * setpoint_timeout * 0.5, (moved, before, after)
    assert abs(after.vn) < 0.05 and after.guided_submode == "hover"
    assert restore - cut > 1.0


# -- fence, battery, EKF: the autopilot's failsafes, not a pilot ------------------------------------------


@pytest.mark.parametrize(
    ("action", "mode", "flight_mode"), [(1, "RTL", FlightMode.RTL), (4, "BRAKE", FlightMode.HOLD)]
)
def test_fence_breach_is_a_failsafe_not_a_pilot(
    made: list[Any], action: int, mode: str, flight_mode: FlightMode
) -> None:
    v, ap = pair(made, {"FENCE_ENABLE": 1, "FENCE_RADIUS": 4.0, "FENCE_ACTION": action})
    fly(ap, v, alt=1.5)
    hlc = Commander(ap, 0.0, 3.0)
    s = state_until(ap, lambda s: s.mode == mode, 5)
    hlc.halt()
    assert v.fence_breached and ("fence breach", mode) in v.failsafe_modes
    assert any(t.endswith("fence breached") for t in v.statustexts)  # AC_Fence, as 4.6.3 SITL says it
    assert s.flight_mode is flight_mode and s.autonomous and s.failsafe == "fence breach", s
    assert not ap.resending  # out of GUIDED: no old target is kept alive
    if mode == "RTL":
        # back inside the fence the breach clears, but the RTL is still the fence's
        vehicle_until(v, lambda s: not v.fence_breached, 5)
        s = state_until(ap, lambda s: s.landed, 8)
        assert s.failsafe == "fence breach" and s.flight_mode is FlightMode.RTL
    else:
        time.sleep(0.5)
        held = ap.state()
        assert held.flight_mode is FlightMode.HOLD and held.failsafe == "fence breach" and held.in_air
        ap.land()  # the operator's LAND is accepted from the autopilot's hold
        s = state_until(ap, lambda s: s.mode == "LAND", 2)
        assert s.flight_mode is FlightMode.LANDING and s.failsafe == ""  # ours, not a failsafe's
        assert state_until(ap, lambda s: s.landed, 6)


def test_battery_failsafe_by_voltage(made: list[Any]) -> None:
    v, ap = pair(
        made,
        {"BATT_LOW_VOLT": 10.5, "BATT_LOW_TIMER": 1, "BATT_FS_LOW_ACT": 2},
        vehicle={"report_remaining": False, "battery_drain": 0.0},
        cells=3,
    )
    s = state_until(ap, lambda s: math.isfinite(s.voltage), 2)
    assert s.battery == -1.0 and not s.battery_known  # many vehicles never estimate the percentage
    assert s.voltage == pytest.approx(12.6, abs=0.01) and s.cells == 3
    assert s.cell_voltage == pytest.approx(4.2, abs=0.01) and s.battery_warning == ""
    fly(ap, v, alt=1.5)
    v.set_voltage(10.2)
    s = state_until(ap, lambda s: s.voltage < 10.3, 2)
    assert s.cell_voltage == pytest.approx(
        3.4, abs=0.01
    )  # the HLC's 3.5 V/cell rule can act before ArduPilot
    assert s.battery_warning == "" and s.mode == "GUIDED"  # BATT_LOW_TIMER has not run out
    s = state_until(ap, lambda s: s.mode == "RTL", 3)
    assert s.battery_warning == "low" and s.failsafe == "battery failsafe", s
    assert s.flight_mode is FlightMode.RTL and s.autonomous
    assert any(t.startswith("Battery 1 is low 10.20V") for t in v.statustexts)
    # ArduPilot keeps its battery failsafe until rebooted (or the pack is reset): still low on the ground,
    # so the HLC refuses the next takeoff
    landed = state_until(ap, lambda s: s.landed, 8)
    assert landed.battery_warning == "low"
    time.sleep(0.5)  # heartbeats on the ground do not make it flicker
    assert ap.state().battery_warning == "low"


def test_battery_cells_from_a_per_cell_monitor_and_critical_state(made: list[Any]) -> None:
    v, ap = pair(
        made,
        {"BATT_LOW_VOLT": 14.0, "BATT_CRT_VOLT": 13.0, "BATT_LOW_TIMER": 1},
        vehicle={"per_cell_monitor": True, "battery_cells": 4, "battery_drain": 0.0},
    )
    s = state_until(ap, lambda s: s.cells == 4, 3)
    assert s.voltage == pytest.approx(16.8, abs=0.01) and s.battery == 100.0
    v.set_voltage(12.8)  # below both thresholds: AP_BattMonitor goes straight to critical
    s = state_until(ap, lambda s: s.battery_warning == "critical", 4)
    assert (
        s.cell_voltage == pytest.approx(3.2, abs=0.01) and s.mode == "STABILIZE"
    )  # on the ground: no action
    assert s.failsafe == ""  # no mode change to explain


def test_ekf_failsafe_lands_and_says_why(made: list[Any]) -> None:
    v, ap = pair(made)
    fly(ap, v, alt=2.0)
    v.fail_ekf()
    s = state_until(ap, lambda s: s.mode == "LAND", 4)
    assert s.failsafe == "EKF failsafe" and s.flight_mode is FlightMode.LANDING and s.autonomous
    assert "EKF variance" in v.statustexts
    assert state_until(ap, lambda s: s.landed, 6).failsafe == "EKF failsafe"


def test_pilot_brake_is_manual_without_a_failsafe(made: list[Any]) -> None:
    v, ap = pair(made, {"FENCE_ENABLE": 1})  # a fence that is not breached explains nothing
    fly(ap, v, alt=1.5)
    assert v.pilot_switch_mode("BRAKE")
    s = state_until(ap, lambda s: s.mode == "BRAKE", 2)
    assert s.flight_mode is FlightMode.MANUAL and not s.autonomous and s.failsafe == ""


# -- the HLC dies: GUID_TIMEOUT stops the copter, the GCS failsafe brings it home ---------------------------


def test_dead_hlc_vehicle_stops_within_guid_timeout_and_returns_by_gcs_failsafe(made: list[Any]) -> None:
    guid, gcs_timeout = 1.0, 1.5
    v, ap = pair(
        made,
        {
            "FS_GCS_ENABLE": 1,
            "SYSID_MYGCS": 245,
            "FS_GCS_TIMEOUT": gcs_timeout,
            "GUID_TIMEOUT": guid,
            "FENCE_ENABLE": 1,
            "BATT_FS_LOW_ACT": 2,
        },
        require_vehicle_failsafes=True,
    )
    assert ap.vehicle_findings == []  # a vehicle set up as docs/ardupilot.md says
    fly(ap, v, alt=1.5)
    ap.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)
    vehicle_until(v, lambda s: s.vn > 2.5, 2)
    last = v.received_of("SET_POSITION_TARGET_LOCAL_NED")[-1].t
    ap.close()  # the HLC process is gone: nothing more is sent, no heartbeat either
    vehicle_until(v, lambda s: s.guided_submode == "hover", guid + 1.0)
    stopped = time.monotonic()
    assert stopped - last <= guid + 0.5
    vehicle_until(v, lambda s: s.mode == "RTL", gcs_timeout + 1.0)
    assert ("GCS failsafe", "RTL") in v.failsafe_modes and "GCS Failsafe" in v.statustexts
    vehicle_until(v, lambda s: not s.armed, 10)
    snap = v.snapshot()
    assert math.hypot(snap.north, snap.east) < 0.5 and snap.alt == 0.0


def test_gcs_failsafe_ignores_heartbeats_from_another_system_id(made: list[Any]) -> None:
    v, ap = pair(made, {"FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 1.0})  # SYSID_MYGCS stays 255; we are 245
    fly(ap, v, alt=1.5)
    ap.close()
    time.sleep(2.0)
    # ArduCopter never heard its GCS: the failsafe never arms, the copter hovers on in GUIDED
    snap = v.snapshot()
    assert snap.mode == "GUIDED" and snap.armed and not v.gcs_failsafe
    assert not [f for f in v.failsafe_modes if f[0] == "GCS failsafe"]


def test_gcs_failsafe_while_the_hlc_lives_is_named(made: list[Any]) -> None:
    """The uplink fails (our HEARTBEATs stop reaching the vehicle) while its telemetry still reaches us."""
    v, ap = pair(made, {"FS_GCS_ENABLE": 1, "SYSID_MYGCS": 245, "FS_GCS_TIMEOUT": 1.0})
    fly(ap, v, alt=1.5)
    v.drop_uplink()
    s = state_until(ap, lambda s: s.mode == "RTL", 3)
    assert s.failsafe == "GCS failsafe" and s.flight_mode is FlightMode.RTL and s.autonomous, s
    assert s.link_age < 0.5  # the downlink is fine: no LLC_DOWN, the HLC follows the RTL
    v.drop_uplink(False)
    assert state_until(ap, lambda s: s.landed, 8).failsafe == "GCS failsafe"
