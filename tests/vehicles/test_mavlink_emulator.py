"""The ArduCopter emulator's own knobs, each driven through the real pymavlink (tests/emulators/mavlink_vehicle.py).

The adapter tests lean on these behaving as ArduCopter does; here the less travelled ones are pinned:
parameter listing and types, the GCS failsafe's other actions and its recovery, the EKF failsafe to
ALT_HOLD, and a battery failsafe escalating from low to critical.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from antalate_lcm.vehicles import FlightMode, Frame
from antalate_lcm.vehicles.mavlink import MavlinkAdapter
from tests.emulators.mavlink_vehicle import PARAMS, MavlinkVehicle
from tests.vehicles.test_mavlink_adapter import FAST, fly, make_ap, state_until, vehicle_until


def pair(made: list[Any], params: dict[str, float], **vehicle: Any) -> tuple[MavlinkVehicle, MavlinkAdapter]:
    v = MavlinkVehicle("127.0.0.1", 0, **{**FAST, "params": params, **vehicle}).start()
    made.append(v)
    # FS_GCS_TIMEOUT is 1 s here (the firmware's least is 2 s; shorter tests): at the adapter's default
    # 1 Hz a heartbeat late by a loaded machine's scheduling tripped the failsafe before the test cut them
    ap = make_ap(v.udp_url, heartbeat_hz=4.0)
    made.append(ap)
    ap.connect()
    return v, ap


def test_parameters_list_index_types_and_unknown_names(made: list[Any]) -> None:
    with pytest.raises(ValueError, match="unknown emulated parameter 'FS_GCS_ENABLED'"):
        MavlinkVehicle(params={"FS_GCS_ENABLED": 1})
    with pytest.raises(ValueError, match="gcs_sysid_param"):
        MavlinkVehicle(gcs_sysid_param="GCS_ID")
    v = MavlinkVehicle("127.0.0.1", 0, **FAST).start()
    made.append(v)
    conn = mavutil.mavlink_connection(v.udp_url, source_system=245, source_component=191)
    try:
        conn.mav.heartbeat_send(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        conn.mav.param_request_list_send(1, 1)
        seen: dict[str, Any] = {}
        deadline = time.monotonic() + 3
        while len(seen) < len(PARAMS) and time.monotonic() < deadline:
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if msg is not None:
                seen[msg.param_id] = msg
        assert set(seen) == set(PARAMS) and all(m.param_count == len(PARAMS) for m in seen.values())
        assert seen["FS_GCS_ENABLE"].param_type == mav2.MAV_PARAM_TYPE_INT8
        assert seen["BATT_LOW_VOLT"].param_value == pytest.approx(10.5)
        while conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.3) is not None:
            pass  # the rest of the list
        index = list(PARAMS).index("GUID_TIMEOUT")
        conn.mav.param_request_read_send(1, 1, b"", index)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
        assert msg is not None and msg.param_id == "GUID_TIMEOUT" and msg.param_index == index
        conn.mav.param_set_send(1, 1, b"FENCE_ACTION", 3.7, mav2.MAV_PARAM_TYPE_INT8)  # an integer parameter
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
        assert msg is not None and msg.param_id == "FENCE_ACTION" and msg.param_value == 4.0
        conn.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, mav2.MAV_PARAM_TYPE_REAL32)
        assert (
            conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5) is None
        )  # no answer, as ArduPilot
    finally:
        conn.close()
    assert v.param("FENCE_ACTION") == 4.0


@pytest.mark.parametrize(("action", "mode"), [(5, "LAND"), (7, "BRAKE")])
def test_gcs_failsafe_actions_and_recovery(made: list[Any], action: int, mode: str) -> None:
    v, ap = pair(made, {"FS_GCS_ENABLE": action, "SYSID_MYGCS": 245, "FS_GCS_TIMEOUT": 1.0})
    fly(ap, v, alt=1.5)
    v.stop_heartbeats()  # the GCS's heartbeats no longer arrive (nor does anything else)
    vehicle_until(v, lambda s: s.mode == mode, 3)
    assert v.gcs_failsafe and ("GCS failsafe", mode) in v.failsafe_modes
    v.resume_heartbeats()
    assert v.wait_until(lambda s: not v.gcs_failsafe, 3) and "GCS Failsafe Cleared" in v.statustexts
    assert v.snapshot().mode == mode  # ArduCopter does not switch back by itself


def test_gcs_failsafe_disarms_on_the_ground(made: list[Any]) -> None:
    v, ap = pair(made, {"FS_GCS_ENABLE": 1, "SYSID_MYGCS": 245, "FS_GCS_TIMEOUT": 1.0})
    assert ap.arm() is True
    v.stop_heartbeats()
    vehicle_until(v, lambda s: not s.armed, 3)
    assert "GCS Failsafe - Disarming" in v.statustexts and v.snapshot().mode == "GUIDED"


def test_ekf_failsafe_to_alt_hold_and_back_to_health(made: list[Any]) -> None:
    v, ap = pair(made, {"FS_EKF_ACTION": 2})
    fly(ap, v, alt=1.5)
    v.fail_ekf()
    s = state_until(ap, lambda s: s.mode == "ALT_HOLD", 3)
    assert s.failsafe == "EKF failsafe" and not s.autonomous  # a pilot must fly ALT_HOLD
    v.fail_ekf(False)
    vehicle_until(v, lambda s: s.ekf_position_ok, 1)


def test_battery_failsafe_escalates_from_low_to_critical(made: list[Any]) -> None:
    v, ap = pair(
        made,
        {
            "BATT_LOW_VOLT": 10.5,
            "BATT_CRT_VOLT": 9.9,
            "BATT_LOW_TIMER": 1,
            "BATT_FS_LOW_ACT": 2,
            "BATT_FS_CRT_ACT": 1,
        },
        battery_drain=0.0,
    )
    fly(ap, v, alt=2.5)
    ap.set_velocity(0.0, 2.0, 0.0, 0.0, Frame.NED)
    v.set_voltage(10.3)
    s = state_until(ap, lambda s: s.mode == "RTL", 3)
    assert s.battery_warning == "low" and s.failsafe == "battery failsafe"
    v.set_voltage(9.8)
    s = state_until(ap, lambda s: s.mode == "LAND", 3)
    assert s.battery_warning == "critical" and s.failsafe == "battery failsafe"
    assert [m for f, m in v.failsafe_modes if f == "battery failsafe"] == ["RTL", "LAND"]
    v.set_voltage(None)  # the voltage recovers under less load: AP_BattMonitor keeps its failsafe
    time.sleep(1.2)
    assert ap.state().battery_warning == "critical" and v.voltage() > 12.0


def test_signature_checked_before_the_timestamp_as_ardupilot_does() -> None:
    """One forged frame with a later timestamp must not make the genuine stream look like replays."""
    from tests.emulators.mavlink_vehicle import _Peer

    key = bytes(range(32))
    peer = _Peer(1, 1, key=key)

    def signed(with_key: bytes, seconds_ahead: float) -> bytes:
        enc = mav2.MAVLink(None, srcSystem=245, srcComponent=191)
        enc.signing.secret_key, enc.signing.sign_outgoing, enc.signing.link_id = with_key, True, 7
        enc.signing.timestamp = int((time.time() - 1420070400 + seconds_ahead) * 1e5)
        frame: bytes = enc.heartbeat_encode(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(enc)
        return frame

    assert [m.get_type() for m in peer.parse(signed(key, 0))] == ["HEARTBEAT"]
    assert peer.parse(signed(b"\x02" * 32, 3600)) == [] and peer.rejected == 1  # forged: a later timestamp
    assert [m.get_type() for m in peer.parse(signed(key, 1))] == ["HEARTBEAT"]  # genuine still accepted
    assert peer.parse(signed(key, 0.5)) == [] and peer.rejected == 2  # a replayed (older) one is not


# -- held to ArduCopter 4.6.3's source: events.cpp, mode_rtl.cpp, mode_land.cpp --------------------------

GCS_FS = {"FS_GCS_ENABLE": 1, "SYSID_MYGCS": 245, "FS_GCS_TIMEOUT": 1.0}


def landing_from(ap: MavlinkAdapter, v: MavlinkVehicle, alt: float) -> None:
    """Take off to `alt` and start the operator's LAND (LAND_SPEED 0.3 m/s: it is still landing later)."""
    fly(ap, v, alt=alt)
    ap.land()
    vehicle_until(v, lambda s: s.mode == "LAND" and s.vd > 0.1, 3)


@pytest.mark.parametrize(("options", "mode"), [(16, "RTL"), (16 | 8, "LAND")])
def test_gcs_failsafe_during_land_returns_unless_fs_options_continue_landing(
    made: list[Any], options: int, mode: str
) -> None:
    """events.cpp failsafe_gcs_on_event: a landing is not exempt; only FS_OPTIONS bit 3 (continue if
    landing) keeps it landing. The adapter names the failsafe either way, and an RTL stays autonomous."""
    v, ap = pair(
        made, {**GCS_FS, "FS_OPTIONS": options}, land_speed=0.3, land_alt_low=10.0, land_speed_high=0.3
    )
    landing_from(ap, v, 3.0)
    v.drop_uplink()  # the GCS's heartbeats stop arriving; the vehicle still reports
    vehicle_until(v, lambda s: v.gcs_failsafe, 3)
    time.sleep(0.3)
    assert v.snapshot().mode == mode and v.snapshot().armed
    if mode == "RTL":
        s = state_until(ap, lambda s: s.mode == "RTL", 3)
        assert s.failsafe == "GCS failsafe" and s.autonomous and ("GCS failsafe", "RTL") in v.failsafe_modes
    else:
        assert "GCS Failsafe - Continuing Landing" in v.statustexts
        assert ap.state().flight_mode is FlightMode.LANDING
    v.drop_uplink(False)


def test_battery_failsafe_during_land_returns_and_the_rtl_is_named(made: list[Any]) -> None:
    """events.cpp handle_battery_failsafe with BATT_FS_LOW_ACT 2 while landing: RTL (as ArduCopter 4.6.3
    SITL does: "Battery 1 is low", "Battery Failsafe", LAND -> RTL, measured); critical + LAND: LAND."""
    v, ap = pair(
        made,
        {
            "BATT_LOW_VOLT": 11.0,
            "BATT_CRT_VOLT": 10.0,
            "BATT_LOW_TIMER": 1,
            "BATT_FS_LOW_ACT": 2,
            "BATT_FS_CRT_ACT": 1,
        },
        land_speed=0.3,
        land_alt_low=10.0,
        land_speed_high=0.3,
        battery_drain=0.0,
    )
    landing_from(ap, v, 3.0)
    v.set_param("SIM_BATT_VOLTAGE", 10.8)
    s = state_until(ap, lambda s: s.mode == "RTL", 4)
    assert s.failsafe == "battery failsafe" and s.autonomous and s.battery_warning == "low"
    assert "Battery Failsafe" in v.statustexts
    v.set_param("SIM_BATT_VOLTAGE", 9.8)
    s = state_until(ap, lambda s: s.mode == "LAND", 4)
    assert s.failsafe == "battery failsafe" and s.battery_warning == "critical"


def test_rtl_climbs_to_rtl_alt_returns_loiters_then_lands(made: list[Any]) -> None:
    """mode_rtl.cpp: the return altitude is max(RTL_ALT, current + RTL_CLIMB_MIN), lowered by the cone
    (RTL_CONE_SLOPE x distance) near home; the copter climbs before it turns home, loiters RTL_LOIT_TIME
    over home, then lands. A swarm's altitude separation therefore changes on an RTL."""
    v, ap = pair(made, {"RTL_ALT": 600, "RTL_CLIMB_MIN": 0, "RTL_LOIT_TIME": 1500}, rtl_speed=6.0)
    fly(ap, v, alt=2.0)
    for _ in range(30):  # 3 s east at 4 m/s: ~10 m from home
        ap.set_velocity(0.0, 4.0, 0.0, 0.0, Frame.NED)
        time.sleep(0.1)
    vehicle_until(v, lambda s: s.east > 8.0, 3)
    ap.rtl()
    s = v.snapshot()
    assert s.rtl_alt == pytest.approx(6.0) and s.rtl_phase == "climb"  # 10 m x 3 > 6 m: RTL_ALT
    east_at_climb = s.east
    vehicle_until(v, lambda s: s.rtl_phase == "return", 6)
    s = v.snapshot()
    assert s.alt >= 5.8 and abs(s.east - east_at_climb) < 1.0  # straight up first, then home
    vehicle_until(v, lambda s: s.rtl_phase == "loiter", 6)
    loiter = time.monotonic()
    vehicle_until(v, lambda s: s.rtl_phase == "land", 3)
    assert time.monotonic() - loiter >= 1.3  # RTL_LOIT_TIME 1.5 s
    vehicle_until(v, lambda s: not s.armed, 10)
    # near home the cone keeps the return low: 1 m out at 2 m, RTL_ALT 6 m -> max(1 x 3, 2 m) = 3 m
    assert state_until(ap, lambda s: not s.armed, 3)
    fly(ap, v, alt=2.0)
    ap.set_velocity(0.0, 1.0, 0.0, 0.0, Frame.NED)
    vehicle_until(v, lambda s: s.east > 0.8, 3)
    ap.rtl()
    assert 2.0 <= v.snapshot().rtl_alt < 4.5


def test_gcs_failsafe_in_a_pilot_mode_continues_by_default(made: list[Any]) -> None:
    """FS_OPTIONS 16 (the default): a GCS failsafe in LOITER leaves the pilot flying; the adapter keeps
    saying MANUAL, no failsafe attributed."""
    v, ap = pair(made, GCS_FS)
    fly(ap, v, alt=1.5)
    assert v.pilot_switch_mode("LOITER")
    state_until(ap, lambda s: s.mode == "LOITER", 2)
    v.drop_uplink()
    vehicle_until(v, lambda s: v.gcs_failsafe, 3)
    assert "GCS Failsafe - Continuing Pilot Control" in v.statustexts
    time.sleep(0.5)
    s = ap.state()
    assert v.snapshot().mode == "LOITER" and s.flight_mode is FlightMode.MANUAL and s.failsafe == ""
    v.drop_uplink(False)


def test_failsafe_land_pauses_4_s_before_descending(made: list[Any]) -> None:
    """mode_land.cpp / events.cpp set_mode_land_with_pause: a failsafe's LAND hovers LAND_WITH_DELAY_MS
    (4 s) first; the adapter names the EKF failsafe while it does."""
    v, ap = pair(made, {})
    fly(ap, v, alt=2.0)
    v.fail_ekf()
    s = state_until(ap, lambda s: s.mode == "LAND", 3)
    assert s.failsafe == "EKF failsafe" and s.flight_mode is FlightMode.LANDING
    start, alt = time.monotonic(), v.snapshot().alt
    time.sleep(3.0)
    assert v.snapshot().alt > alt - 0.2  # still hovering
    vehicle_until(v, lambda s: s.alt < alt - 0.5, 3)
    assert time.monotonic() - start >= 3.0
    v.fail_ekf(False)
    assert v.wait_until(lambda s: "EKF Failsafe Cleared" in v.statustexts, 2)


def test_radio_failsafe_rtl_is_named_and_clears(made: list[Any]) -> None:
    """events.cpp failsafe_radio_on_event with FS_THR_ENABLE 1: "Radio Failsafe" and RTL (ArduCopter 4.6.3
    SITL with SIM_RC_FAIL 1 does it within 0.1 s, measured); the adapter says "RC failsafe"."""
    v, ap = pair(made, {})
    fly(ap, v, alt=2.0)
    v.set_param("SIM_RC_FAIL", 1)
    s = state_until(ap, lambda s: s.mode == "RTL", 3)
    assert s.failsafe == "RC failsafe" and s.autonomous and "Radio Failsafe" in v.statustexts
    v.set_param("SIM_RC_FAIL", 0)
    assert v.wait_until(lambda s: "Radio Failsafe Cleared" in v.statustexts, 2)


def test_gps_loss_lands_by_the_ekf_failsafe_and_recovers(made: list[Any]) -> None:
    """SIM_GPS_DISABLE 1: the EKF dead-reckons ~6 s (measured on 4.6.3 SITL), then "EKF variance",
    "EKF Failsafe: changed to LAND Mode"; GPS back: "EKF Failsafe Cleared" and the vehicle ready again."""
    v, ap = pair(made, {})
    fly(ap, v, alt=2.0)
    v.set_param("SIM_GPS_DISABLE", 1)
    s = state_until(ap, lambda s: s.mode == "LAND", 10)
    assert s.failsafe == "EKF failsafe" and "EKF Failsafe: changed to LAND Mode" in v.statustexts
    vehicle_until(v, lambda s: not s.armed, 12)
    v.set_param("SIM_GPS_DISABLE", 0)
    assert v.wait_until(lambda s: "EKF Failsafe Cleared" in v.statustexts and s.ekf_position_ok, 3)
    assert ap.arm() is True  # nothing the failsafe left behind stays latched
