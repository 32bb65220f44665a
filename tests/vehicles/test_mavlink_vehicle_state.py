"""`mavlink.vehicle` and `mavlink.dialect`: ArduCopter telemetry into the adapter's picture (pure, no sockets)."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import FlightMode
from antalate_lcm.vehicles.mavlink import dialect
from antalate_lcm.vehicles.mavlink.vehicle import REBOOT_GAP, Vehicle

GUIDED, LOITER, RTL = (dialect.COPTER_MODES[m] for m in ("GUIDED", "LOITER", "RTL"))
ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED | mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def heartbeat(custom_mode: int, armed: bool = False, status: int = mav.MAV_STATE_STANDBY) -> Any:
    base = ARMED if armed else mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    return mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, custom_mode, status, 3
    )


def ack(command: int, result: int, target_system: int = 245) -> Any:
    return mav.MAVLink_command_ack_message(command, result, 0, 0, target_system, 191)


def test_mode_names_and_unknown_modes() -> None:
    assert dialect.mode_name(GUIDED) == "GUIDED" and dialect.mode_name(250) == "MODE_250"
    assert dialect.result_name(None) == "no COMMAND_ACK"
    assert dialect.result_name(mav.MAV_RESULT_TEMPORARILY_REJECTED) == "TEMPORARILY_REJECTED"
    assert dialect.cmd_name(mav.MAV_CMD_NAV_TAKEOFF) == "MAV_CMD_NAV_TAKEOFF"
    assert dialect.status_name(mav.MAV_STATE_STANDBY) == "STANDBY" and dialect.status_name(None) == "unknown"


def test_velocity_target_is_velocity_and_yaw_rate_in_rad_per_s() -> None:
    msg = dialect.velocity_target((1, 1), 2**32 + 5, mav.MAV_FRAME_LOCAL_NED, 1.0, -2.0, 0.5, 90.0)
    assert msg.time_boot_ms == 5 and msg.type_mask == dialect.VELOCITY_TYPE_MASK == 0x05C7
    assert (msg.vx, msg.vy, msg.vz) == (1.0, -2.0, 0.5) and msg.yaw_rate == pytest.approx(math.pi / 2)


def test_only_an_autopilot_heartbeat_is_the_vehicle() -> None:
    codec = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = codec.parse_buffer(heartbeat(0).pack(codec))[0]
    gcs = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    gcs = codec.parse_buffer(gcs.pack(codec))[0]
    assert dialect.is_autopilot(hb, 0, 0) and dialect.is_autopilot(hb, 1, 1)
    assert not dialect.is_autopilot(hb, 2, 0) and not dialect.is_autopilot(gcs, 0, 0)


def test_heartbeat_sets_mode_and_arming_and_drops_the_setpoint_out_of_guided() -> None:
    v = Vehicle()
    assert v.update(heartbeat(GUIDED, armed=True, status=mav.MAV_STATE_ACTIVE), 1.0).drop_setpoint is False
    assert v.armed and v.mode == "GUIDED" and v.in_air  # no EXTENDED_SYS_STATE: armed + ACTIVE is flying
    assert v.heartbeats == 1 and v.heartbeat_at == 1.0 and v.heartbeat_msg == 1
    assert v.update(heartbeat(LOITER, armed=True), 1.5).drop_setpoint  # a pilot's switch
    assert v.update(heartbeat(GUIDED, armed=False), 2.0).drop_setpoint  # disarmed
    state = v.vehicle_state(2.5)
    assert state.link_age == pytest.approx(0.5) and not state.armed


def test_heartbeat_after_a_silence_asks_for_streams_again() -> None:
    v = Vehicle()
    assert not v.update(heartbeat(0), 1.0).request_streams
    assert not v.update(heartbeat(0), 1.0 + REBOOT_GAP).request_streams
    assert v.update(heartbeat(0), 2.0 + 2 * REBOOT_GAP).request_streams


def test_a_mode_we_commanded_is_no_failsafe_and_loiter_is_a_pilot() -> None:
    v = Vehicle(command_window=3.0)
    v.update(heartbeat(GUIDED, armed=True), 0.0)
    v.commanded = ("RTL", 1.0)
    v.update(heartbeat(RTL, armed=True), 2.0)
    assert v.vehicle_state(2.0).flight_mode is FlightMode.RTL and v.failsafes.reason == ""
    v.update(heartbeat(LOITER, armed=True), 3.0)
    assert v.vehicle_state(3.0).flight_mode is FlightMode.MANUAL


def test_fence_status_names_the_failsafe_of_a_mode_change() -> None:
    v = Vehicle()
    v.update(heartbeat(GUIDED, armed=True), 0.0)
    v.update(mav.MAVLink_fence_status_message(1, 1, mav.FENCE_BREACH_MAXALT, 0, 0), 0.5)
    v.update(heartbeat(RTL, armed=True), 1.0)
    state = v.vehicle_state(1.0)
    assert v.fence_breached and state.failsafe == "fence breach" and state.autonomous


def test_acks_match_by_command_after_the_mark_and_ignore_other_stations() -> None:
    v = Vehicle(source_system=245)
    mark = v.messages
    v.update(ack(mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_RESULT_IN_PROGRESS), 0.0)
    assert v.ack_after(mav.MAV_CMD_NAV_TAKEOFF, mark) is None  # not final yet
    assert v.ack_after(mav.MAV_CMD_NAV_TAKEOFF, mark, final=False) == mav.MAV_RESULT_IN_PROGRESS
    v.update(ack(mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_RESULT_DENIED, target_system=255), 0.1)  # Mission Planner's
    assert v.ack_after(mav.MAV_CMD_NAV_TAKEOFF, mark) is None
    v.update(ack(mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_RESULT_ACCEPTED), 0.2)
    assert v.ack_after(mav.MAV_CMD_NAV_TAKEOFF, mark) == mav.MAV_RESULT_ACCEPTED
    assert v.ack_after(mav.MAV_CMD_NAV_TAKEOFF, v.messages) is None  # nothing after the latest


def test_position_battery_and_params() -> None:
    v = Vehicle()
    v.update(mav.MAVLink_global_position_int_message(0, 0, 0, 0, 1500, 0, 0, 0, 65535), 0.0)
    assert math.isnan(v.lat) and v.alt == 1.5 and v.heading is None  # no fix yet: lat/lon 0
    v.update(mav.MAVLink_attitude_message(0, 0, 0, -math.pi / 2, 0, 0, 0), 0.0)
    assert v.vehicle_state(0.0).heading == pytest.approx(270.0)
    cells = [4100, 4100, 4100, 4100] + [0xFFFF] * 6
    v.update(
        mav.MAVLink_battery_status_message(
            0, 0, 0, 0, cells, -1, -1, -1, 42, 0, mav.MAV_BATTERY_CHARGE_STATE_LOW, [0, 0, 0, 0], 0, 0
        ),
        1.0,
    )
    state = v.vehicle_state(1.0)
    assert state.cells == 4 and state.voltage == pytest.approx(16.4) and state.battery == 42
    assert state.battery_warning == "low" and "battery failsafe" in v.failsafes.active
    v.update(mav.MAVLink_param_value_message(b"FS_GCS_ENABLE", 1.0, mav.MAV_PARAM_TYPE_INT8, 1, 0), 1.0)
    assert v.params["FS_GCS_ENABLE"] == 1.0 and v.param_after("FS_GCS_ENABLE", 0)


def test_statustext_reasons_and_readiness() -> None:
    v = Vehicle()
    v.update(heartbeat(0, status=mav.MAV_STATE_BOOT), 0.0)
    assert any("still booting" in r for r in v.not_ready()) and len(v.not_ready()) == 3
    mark = v.messages
    v.update(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_CRITICAL, b"PreArm: Need 3D Fix", 0, 0), 0.1)
    assert v.texts_since(mark) == "PreArm: Need 3D Fix" == v.latest_prearm()
    v.update(heartbeat(0), 0.2)
    v.update(mav.MAVLink_ekf_status_report_message(dialect.EKF_NEEDED, 0, 0, 0, 0, 0, 0), 0.2)
    v.update(mav.MAVLink_gps_raw_int_message(0, 3, 0, 0, 0, 0, 0, 0, 0, 10), 0.2)
    assert v.not_ready() == []


BATTERY_BIT = mav.MAV_SYS_STATUS_SENSOR_BATTERY


def sys_status(healthy: bool, mv: int, percent: int) -> Any:
    """SYS_STATUS with only the battery bit, as ArduCopter 4.6.3 sends it (present and enabled)."""
    return mav.MAVLink_sys_status_message(
        BATTERY_BIT, BATTERY_BIT, BATTERY_BIT if healthy else 0, 0, mv, -1, percent, 0, 0, 0, 0, 0, 0
    )


def test_a_battery_not_yet_reported_is_unknown_never_low() -> None:
    """ArduCopter 4.6.3 SITL, agent connected before the monitor reads: the first SYS_STATUS says the
    battery unhealthy with 0 mV and -1 % (measured), the next 12.6 V, 100 %, healthy. That first one was
    latched as a battery failsafe and every take-off refused for as long as the agent ran (issue #25)."""
    v = Vehicle()
    v.update(heartbeat(0, status=mav.MAV_STATE_BOOT), 0.0)
    v.update(sys_status(False, 0, -1), 0.1)
    state = v.vehicle_state(0.1)
    assert (
        state.battery_warning == ""
        and not state.battery_known
        and "battery failsafe" not in v.failsafes.active
    )
    assert any("battery unknown" in r for r in v.not_ready())
    v.update(sys_status(True, 12600, 100), 0.2)
    state = v.vehicle_state(0.2)
    assert state.battery_warning == "" and state.battery == 100 and state.voltage == pytest.approx(12.6)
    assert not any("battery" in r for r in v.not_ready())


def test_the_health_bit_is_a_level_and_a_healthy_report_clears_a_kept_warning() -> None:
    v = Vehicle()
    v.update(heartbeat(GUIDED, armed=True, status=mav.MAV_STATE_ACTIVE), 0.0)
    v.update(sys_status(False, 10200, 20), 1.0)  # read, and failsafed (has_failsafed)
    assert v.vehicle_state(1.0).battery_warning == "failsafe" and "battery failsafe" in v.failsafes.active
    v.update(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, b"Battery 1 is low 10.20V", 0, 0), 1.1)
    assert v.vehicle_state(1.1).battery_warning == "low"
    # the vehicle reports its battery healthy and not failsafed (a fresh pack, a monitor reset): nothing stays
    v.update(sys_status(True, 12500, 95), 2.0)
    assert v.vehicle_state(2.0).battery_warning == "" and "battery failsafe" not in v.failsafes.active
    # a monitor that stops reading in flight is unknown, not low
    v.update(sys_status(False, 0, -1), 3.0)
    assert v.vehicle_state(3.0).battery_warning == "" and any("battery unknown" in r for r in v.not_ready())


def test_radio_failsafe_names_the_rtl_and_clears_with_the_radio() -> None:
    """ArduCopter 4.6.3 SITL, SIM_RC_FAIL 1 in GUIDED (FS_THR_ENABLE 1): "Radio Failsafe", the RC_RECEIVER
    health bit cleared and RTL in the same tenth of a second (measured); the radio back: "Radio Failsafe
    Cleared" and the bit set again. The RTL is the radio failsafe's, not a pilot's and not unexplained."""
    rc = mav.MAV_SYS_STATUS_SENSOR_RC_RECEIVER

    def status(healthy: bool) -> Any:
        return mav.MAVLink_sys_status_message(
            rc, rc, rc if healthy else 0, 0, 12600, -1, 100, 0, 0, 0, 0, 0, 0
        )

    v = Vehicle()
    v.update(heartbeat(GUIDED, armed=True, status=mav.MAV_STATE_ACTIVE), 0.0)
    v.update(status(True), 0.5)
    v.update(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, b"Radio Failsafe", 0, 0), 1.0)
    v.update(heartbeat(RTL, armed=True, status=mav.MAV_STATE_CRITICAL), 1.05)
    v.update(status(False), 1.1)
    state = v.vehicle_state(1.1)
    assert state.failsafe == "RC failsafe" and state.flight_mode is FlightMode.RTL and state.autonomous
    v.update(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, b"Radio Failsafe Cleared", 0, 0), 9.0)
    v.update(status(True), 9.1)
    assert "RC failsafe" not in v.failsafes.active


def test_a_command_is_spent_once_the_vehicle_leaves_for_another_mode() -> None:
    """The operator's LAND, a battery failsafe's RTL, then its critical LAND -- all within the command
    window: the last LAND is the failsafe's, not ours (ArduCopter 4.6.3: BATT_FS_LOW_ACT 2, CRT_ACT 1)."""
    land = dialect.COPTER_MODES["LAND"]
    v = Vehicle(command_window=5.0)
    v.update(heartbeat(GUIDED, armed=True), 0.0)
    v.commanded = ("LAND", 0.5)
    v.update(heartbeat(land, armed=True), 1.0)
    assert v.failsafes.reason == ""
    v.update(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, b"Battery Failsafe", 0, 0), 2.0)
    v.update(heartbeat(RTL, armed=True), 2.1)
    assert v.failsafes.reason == "battery failsafe"
    v.update(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, b"Battery Failsafe", 0, 0), 3.0)
    v.update(heartbeat(land, armed=True), 3.1)
    assert v.failsafes.reason == "battery failsafe" and v.vehicle_state(3.1).failsafe == "battery failsafe"
