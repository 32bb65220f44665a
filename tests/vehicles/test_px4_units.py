"""The ``px4`` adapter's pure rules: PX4's modes, mode ownership and failsafes, readiness, OFFBOARD streaming
and the failsafe-parameter checks (hand-made MAVLink messages, no sockets, no SITL)."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.core.config import load_config
from antalate_lcm.runtime.agent import validate
from antalate_lcm.vehicles.base import FlightMode, Frame
from antalate_lcm.vehicles.mavlink.setpoints import Verdict
from antalate_lcm.vehicles.px4 import Px4Adapter, Px4Params, failsafe, modes, vehicle_checks
from antalate_lcm.vehicles.px4.offboard import OffboardRules
from antalate_lcm.vehicles.px4.vehicle import Px4Vehicle, decode_param, encode_param
from tests import REPO

HOLD = modes.pack(modes.AUTO, modes.AUTO_LOITER)
TAKEOFF = modes.pack(modes.AUTO, modes.AUTO_TAKEOFF)
OFFBOARD = modes.pack(modes.OFFBOARD, 0)
RTL = modes.pack(modes.AUTO, modes.AUTO_RTL)
POSCTL = modes.pack(modes.POSCTL, 0)
ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED | mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def heartbeat(custom_mode: int, armed: bool = True, status: int = mav.MAV_STATE_ACTIVE) -> Any:
    base = ARMED if armed else mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    return mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, custom_mode, status, 3
    )


def in_air() -> Any:
    return mav.MAVLink_extended_sys_state_message(0, mav.MAV_LANDED_STATE_IN_AIR)


def flying(mode: int = HOLD, *, ours: bool = True) -> Px4Vehicle:
    v = Px4Vehicle()
    v.update(in_air(), 0.0)
    v.update(heartbeat(mode), 0.0)
    v.ours = ours
    return v


def test_custom_mode_packs_main_and_sub_as_px4_heartbeats_show_them() -> None:
    # values seen from PX4 v1.15.4 SITL: Hold 0x03040000, take-off 0x02040000, OFFBOARD 0x00060000, RTL 0x05040000
    assert (HOLD, TAKEOFF, OFFBOARD, RTL) == (0x03040000, 0x02040000, 0x00060000, 0x05040000)
    assert modes.split(0x05040000) == (4, 5)
    names = [
        modes.mode_name(m)
        for m in (HOLD, TAKEOFF, OFFBOARD, RTL, POSCTL, modes.pack(4, 77), modes.pack(42, 0))
    ]
    assert names == ["AUTO.LOITER", "AUTO.TAKEOFF", "OFFBOARD", "AUTO.RTL", "POSCTL", "AUTO.77", "MODE_42.0"]


@pytest.mark.parametrize(
    ("mode", "ours", "reason", "expected"),
    [
        ("OFFBOARD", True, "", (FlightMode.GUIDED, True, "")),
        ("AUTO.LOITER", True, "", (FlightMode.GUIDED, True, "")),  # the end of our take-off
        ("AUTO.LOITER", False, "", (FlightMode.MANUAL, False, "")),  # another ground station's Hold
        ("AUTO.LOITER", False, "offboard loss", (FlightMode.HOLD, True, "offboard loss")),
        ("AUTO.RTL", False, "battery failsafe", (FlightMode.RTL, True, "battery failsafe")),
        ("AUTO.RTL", False, "", (FlightMode.RTL, True, "")),
        ("AUTO.LAND", True, "", (FlightMode.LANDING, True, "")),
        ("POSCTL", False, "", (FlightMode.MANUAL, False, "")),
        ("OFFBOARD", False, "", (FlightMode.MANUAL, False, "")),  # somebody else's OFFBOARD
    ],
)
def test_classify(mode: str, ours: bool, reason: str, expected: tuple[FlightMode, bool, str]) -> None:
    assert modes.classify(mode, ours=ours, failsafe=reason) == expected


@pytest.mark.parametrize(
    ("value", "ptype"),
    [(5, mav.MAV_PARAM_TYPE_INT32), (-1, mav.MAV_PARAM_TYPE_INT32), (0.7, mav.MAV_PARAM_TYPE_REAL32)],
)
def test_integer_parameters_are_packed_byte_wise(value: float, ptype: int) -> None:
    wire = encode_param(value, ptype)
    assert decode_param(wire, ptype) == pytest.approx(value)
    if ptype == mav.MAV_PARAM_TYPE_INT32 and value > 0:
        assert wire < 1e-40  # what PX4 really sends for COM_DL_LOSS_T = 10: 1.4e-44


def test_param_value_from_px4_is_decoded() -> None:
    v = Px4Vehicle()
    v.update(
        mav.MAVLink_param_value_message(
            b"COM_DL_LOSS_T", 1.401298464324817e-44, mav.MAV_PARAM_TYPE_INT32, 1, 0
        ),
        0.0,
    )
    v.update(mav.MAVLink_param_value_message(b"COM_OF_LOSS_T", 1.0, mav.MAV_PARAM_TYPE_REAL32, 1, 0), 0.0)
    assert v.params == {"COM_DL_LOSS_T": 10.0, "COM_OF_LOSS_T": 1.0}


def test_readiness_needs_px4_prearm_bit_home_estimator_and_fix() -> None:
    v = Px4Vehicle()
    v.update(heartbeat(HOLD, armed=False, status=mav.MAV_STATE_UNINIT), 0.0)
    assert len(v.not_ready()) == 5
    v.update(heartbeat(HOLD, armed=False, status=mav.MAV_STATE_STANDBY), 1.0)
    bits = mav.MAV_SYS_STATUS_PREARM_CHECK
    v.update(mav.MAVLink_sys_status_message(bits, bits, bits, 0, 16200, -1, 100, 0, 0, 0, 0, 0, 0), 1.0)
    v.update(
        mav.MAVLink_home_position_message(454671111, -737578361, 33435, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0), 1.0
    )
    v.update(mav.MAVLink_gps_raw_int_message(0, 3, 0, 0, 0, 0, 0, 0, 0, 10), 1.0)
    estimator = mav.MAVLink_estimator_status_message(0, 0x00E4, 0, 0, 0, 0, 0, 0, 0, 0)
    v.update(estimator, 1.0)
    assert v.not_ready() == ["estimator has no absolute horizontal position (flags 0x00e4)"]
    estimator.flags = 0x0037
    v.update(estimator, 2.0)
    assert v.not_ready() == [] and v.home == (45.4671111, -73.7578361, 33.435)


def test_our_takeoff_ends_in_our_hold_and_our_offboard_is_ours() -> None:
    v = flying(HOLD)
    v.commanded = ("AUTO.TAKEOFF", 1.0)
    v.update(heartbeat(TAKEOFF), 1.5)
    v.update(heartbeat(HOLD), 9.0)  # PX4 switched by itself, long after the command
    assert v.ours and v.vehicle_state(9.0).flight_mode is FlightMode.GUIDED
    v.commanded = ("OFFBOARD", 10.0)
    v.update(heartbeat(OFFBOARD), 10.2)
    assert v.ours and v.flying_guided


@pytest.mark.parametrize(
    ("mode", "armed", "status", "expected"),
    [
        (HOLD, True, mav.MAV_STATE_ACTIVE, FlightMode.GUIDED),  # hovering after our take-off or our stop
        (OFFBOARD, True, mav.MAV_STATE_ACTIVE, FlightMode.GUIDED),
        (HOLD, True, mav.MAV_STATE_CRITICAL, FlightMode.HOLD),  # a failsafe's Hold stays the failsafe's
        (POSCTL, True, mav.MAV_STATE_ACTIVE, FlightMode.MANUAL),  # a pilot's stick mode
    ],
)
def test_an_adapter_restarted_in_flight_takes_px4s_hold_and_offboard_as_its_own(
    mode: int, armed: bool, status: int, expected: FlightMode
) -> None:
    """The real PX4 showed it: an HLC restarted in flight found PX4 in Hold, and took it for a pilot."""
    v = Px4Vehicle()
    v.update(in_air(), 0.0)
    v.update(heartbeat(mode, armed, status), 0.0)  # the first HEARTBEAT this adapter hears
    assert v.vehicle_state(0.0).flight_mode is expected
    assert v.ours is (expected is FlightMode.GUIDED)
    v.update(heartbeat(POSCTL, armed, status), 1.0)  # the pilot's next mode change is still a pilot's
    assert v.vehicle_state(1.0).flight_mode is not FlightMode.GUIDED


def test_a_pilots_mode_change_is_manual_and_drops_the_setpoint() -> None:
    v = flying(OFFBOARD)
    update = v.update(heartbeat(HOLD), 2.0)  # another ground station's Hold, no failsafe flag
    state = v.vehicle_state(2.0)
    assert update.drop_setpoint and not state.autonomous and state.flight_mode is FlightMode.MANUAL
    assert state.failsafe == ""


def test_leaving_offboard_with_the_failsafe_flag_is_offboard_loss_and_its_action_keeps_the_reason() -> None:
    v = flying(OFFBOARD)
    v.update(heartbeat(HOLD, status=mav.MAV_STATE_CRITICAL), 2.0)
    state = v.vehicle_state(2.0)
    assert (state.flight_mode, state.autonomous, state.failsafe) == (
        FlightMode.HOLD,
        True,
        failsafe.OFFBOARD_LOSS,
    )
    v.update(heartbeat(RTL, status=mav.MAV_STATE_CRITICAL), 7.0)  # COM_FAIL_ACT_T later: the action
    assert v.vehicle_state(7.0).failsafe == failsafe.OFFBOARD_LOSS
    assert v.vehicle_state(7.0).flight_mode is FlightMode.RTL


def test_battery_evidence_names_the_failsafe() -> None:
    v = flying(OFFBOARD)
    low = mav.MAVLink_battery_status_message(
        0, 0, 0, 0, [15000] + [65535] * 9, 0, 0, 0, 12, charge_state=mav.MAV_BATTERY_CHARGE_STATE_LOW
    )
    v.update(low, 1.0)
    v.update(heartbeat(RTL, status=mav.MAV_STATE_CRITICAL), 1.5)
    state = v.vehicle_state(1.5)
    assert state.failsafe == "battery failsafe" and state.flight_mode is FlightMode.RTL
    assert state.battery_warning == "low"


def test_a_long_silence_before_the_failsafe_is_the_data_link() -> None:
    v = flying(HOLD, ours=False)
    v.datalink_loss_after = 3.0
    v.update(heartbeat(HOLD), 1.0)
    v.update(heartbeat(RTL, status=mav.MAV_STATE_CRITICAL), 5.0)  # 4 s of nothing, then RTL
    assert v.vehicle_state(5.0).failsafe == "GCS failsafe"


def test_failsafe_priority_and_texts() -> None:
    assert (
        failsafe.reason(left_offboard=True, battery=True, fence=False, link_lost=True) == "battery failsafe"
    )
    assert (
        failsafe.reason(left_offboard=False, battery=False, fence=False, link_lost=False) == failsafe.UNKNOWN
    )
    assert failsafe.text_evidence("Geofence violated") == "fence breach"
    assert failsafe.text_evidence("Data link lost") == "GCS failsafe"
    assert failsafe.text_evidence("Failsafe activated\t") == ""


RULES = OffboardRules(resend_period=0.1, timeout=1.0, stale_after=1.0, lead=0.5)


def test_offboard_stream_switches_only_from_our_hold_with_a_moving_setpoint() -> None:
    v = flying(HOLD)
    v.update(in_air(), 1.0)
    east = RULES.new(Frame.NED, 0.0, 1.0, 0.0, 0.0, 1.0)
    zero = RULES.new(Frame.NED, 0.0, 0.0, 0.0, 0.0, 1.0)
    assert RULES.judge(v, east, 1.0) is Verdict.SEND and RULES.judge(v, zero, 1.0) is Verdict.IGNORE
    assert not RULES.switch_due(v, east, 1.0, 1.2) and RULES.switch_due(v, east, 1.0, 1.5)
    assert not RULES.switch_due(v, zero, 1.0, 1.5)
    v.ours = False  # a pilot's Hold: never taken over
    assert RULES.judge(v, east, 1.0) is Verdict.IGNORE and not RULES.switch_due(v, east, 1.0, 1.5)


def test_offboard_stream_turns_a_stale_setpoint_into_a_hover_and_never_feeds_a_stale_link() -> None:
    v = flying(OFFBOARD)
    v.update(in_air(), 1.0)
    sp = RULES.keep(RULES.new(Frame.NED, 0.0, 1.0, 0.0, 0.0, 1.0))
    kept, verdict = RULES.due(v, sp, 1.1)
    assert verdict is Verdict.SEND and kept is not None and kept.vy == 1.0
    v.update(in_air(), 2.0)
    kept, verdict = RULES.due(v, kept, 2.05)  # the HLC has been silent for 1.05 s
    assert verdict is Verdict.SEND and kept is not None and kept.zero
    kept, verdict = RULES.due(v, kept, 3.1)  # nothing heard from PX4 for 1.1 s
    assert verdict is Verdict.WITHHOLD and kept is not None and kept.zero
    v.update(in_air(), 3.2)
    kept, verdict = RULES.due(v, kept, 3.2)
    assert verdict is Verdict.SEND and kept is not None and kept.zero  # the stream goes on: a stop
    assert RULES.stop_after_stale(v, 3.2) is None


def test_vehicle_checks_name_what_leaves_px4_unprotected() -> None:
    defaults = {  # PX4 v1.15.4 SIH defaults as read from SITL
        "COM_OF_LOSS_T": 1.0,
        "COM_OBL_RC_ACT": 0.0,
        "NAV_DLL_ACT": 0.0,
        "COM_DL_LOSS_T": 10.0,
        "COM_FAIL_ACT_T": 5.0,
        "COM_LOW_BAT_ACT": 2.0,
        "GF_ACTION": 2.0,
    }
    found = {f.param: f.want for f in vehicle_checks.check(defaults, max_offboard_loss_timeout=1.0)}
    assert found == {"COM_OBL_RC_ACT": 5, "NAV_DLL_ACT": 2}
    bad = {
        **defaults,
        "COM_OF_LOSS_T": 3.0,
        "COM_LOW_BAT_ACT": 0.0,
        "GF_ACTION": 1.0,
        "NAV_DLL_ACT": 2.0,
        "COM_OBL_RC_ACT": 5.0,
    }
    found = {f.param: f.want for f in vehicle_checks.check(bad, max_offboard_loss_timeout=1.0)}
    assert found == {"COM_OF_LOSS_T": 1.0, "COM_LOW_BAT_ACT": 3, "GF_ACTION": 3}
    missing = vehicle_checks.check({}, max_offboard_loss_timeout=1.0)
    assert {f.param for f in missing} == set(vehicle_checks.READ) and not any(f.settable for f in missing)
    assert all(math.isfinite(f.want or 0) for f in missing)


def test_params_have_px4_defaults_and_refuse_arducopters_guid_timeout() -> None:
    p = Px4Params()
    assert p.connection == "udpin:127.0.0.1:14540" and p.velocity_resend_hz == 10.0
    with pytest.raises(ValueError, match="max_guid_timeout is ArduCopter"):
        Px4Adapter({"max_guid_timeout": 2.0})
    with pytest.raises(ValueError, match="px4 autopilot parameter 'velocity_resend_hz'"):
        Px4Adapter({"velocity_resend_hz": 1.0})  # PX4 needs >= 2 Hz
    with pytest.raises(ValueError, match="offboard_lead"):
        Px4Adapter({"offboard_lead": "1"})


@pytest.mark.parametrize(
    ("frame", "wire"), [(Frame.NED, mav.MAV_FRAME_LOCAL_NED), (Frame.BODY, mav.MAV_FRAME_BODY_NED)]
)
def test_setpoints_use_the_frames_px4_accepts(frame: Frame, wire: int) -> None:
    """PX4 1.15.4 SITL answered BODY_OFFSET_NED (ArduCopter's BODY) with "coordinate frame 9
    unsupported" and dropped the set-point: BODY is BODY_NED for PX4."""
    rules = OffboardRules(resend_period=0.1, timeout=1.0, stale_after=1.0)
    assert rules.new(frame, 1.0, 0.0, 0.0, 0.0, 0.0).frame == wire
    assert rules.hover(0.0).frame == mav.MAV_FRAME_LOCAL_NED


def test_the_px4_sitl_example_loads_and_flies_sitl_instance_0() -> None:
    """examples/px4_sitl.toml through the config loader and the adapter's own parameter model: PX4
    SITL instance 0's offboard link, the defaults docs/px4.md gives."""
    config = load_config(REPO / "examples" / "px4_sitl.toml")
    validate(config)
    assert config.hlc.autopilot == "px4"
    params = Px4Params.model_validate(config.hlc.autopilot_params)
    assert params.connection == "udpin:127.0.0.1:14540"
    assert (params.velocity_resend_hz, params.offboard_lead, params.max_offboard_loss_timeout) == (
        10.0,
        1.0,
        1.0,
    )
