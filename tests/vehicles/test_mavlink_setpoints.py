"""`mavlink.setpoints`: when a velocity set-point may go to ArduCopter, and its resend (pure, no sockets)."""

from __future__ import annotations

from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.mavlink.dialect import COPTER_MODES
from antalate_lcm.vehicles.mavlink.setpoints import ZERO_RESEND, SetpointRules, Verdict
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle

RULES = SetpointRules(resend_period=0.1, timeout=1.0, stale_after=1.0)


def heartbeat(mode: str, armed: bool) -> Any:
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR,
        mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base,
        COPTER_MODES[mode],
        mav.MAV_STATE_ACTIVE,
        3,
    )


def vehicle(mode: str = "GUIDED", armed: bool = True, landed: int = mav.MAV_LANDED_STATE_IN_AIR) -> Vehicle:
    v = Vehicle()
    v.update(heartbeat(mode, armed), 0.0)
    v.update(mav.MAVLink_extended_sys_state_message(0, landed), 0.0)
    return v


def test_sent_in_guided_flight_ignored_outside_guided() -> None:
    sp = RULES.new(Frame.NED, 1.0, 0.0, 0.0, 0.0, 0.5)
    assert sp.frame == mav.MAV_FRAME_LOCAL_NED and sp.next_send == pytest.approx(0.6)
    assert RULES.judge(vehicle(), sp, 0.5) is Verdict.SEND
    assert RULES.judge(vehicle(mode="LOITER"), sp, 0.5) is Verdict.IGNORE
    assert RULES.judge(vehicle(armed=False), sp, 0.5) is Verdict.IGNORE
    assert RULES.keep(sp) is sp and SetpointRules(0.0, 1.0, 1.0).keep(sp) is None  # no resend configured


def test_withheld_from_a_stale_link() -> None:
    v = vehicle()  # last message at 0.0
    sp = RULES.new(Frame.BODY, 1.0, 0.0, 0.0, 0.0, 1.5)
    assert RULES.judge(v, sp, 1.0) is Verdict.SEND
    assert RULES.judge(v, sp, 1.5) is Verdict.WITHHOLD
    assert RULES.judge(Vehicle(commanded=None), sp, 0.0) is Verdict.IGNORE  # nothing heard: not even armed


def test_no_zero_setpoint_during_the_takeoff_climb() -> None:
    climbing = vehicle(landed=mav.MAV_LANDED_STATE_TAKEOFF)
    assert RULES.judge(climbing, RULES.new(Frame.NED, 0.0, 0.0, 0.0, 0.0, 0.1), 0.1) is Verdict.IGNORE
    assert RULES.judge(climbing, RULES.new(Frame.NED, 0.0, 0.0, -1.0, 0.0, 0.1), 0.1) is Verdict.SEND


def test_resend_until_setpoint_timeout_never_older() -> None:
    v = vehicle()
    sp = RULES.new(Frame.NED, 1.0, 0.0, 0.0, 0.0, 0.0)
    assert RULES.due(v, sp, 0.05) == (sp, Verdict.IGNORE)  # not due yet
    v.rx_at = 0.9
    kept, verdict = RULES.due(v, sp, 0.1)
    assert kept is sp and verdict is Verdict.SEND and sp.next_send == pytest.approx(0.2)
    assert RULES.due(v, sp, 1.0) == (None, Verdict.IGNORE)  # 1 s old: setpoint_timeout


def test_zero_setpoint_resent_for_one_second_only() -> None:
    rules = SetpointRules(resend_period=0.1, timeout=5.0, stale_after=10.0)
    v = vehicle()
    zero = rules.new(Frame.NED, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert rules.due(v, zero, ZERO_RESEND - 0.05)[1] is Verdict.SEND
    assert rules.due(v, zero, ZERO_RESEND + 0.05) == (None, Verdict.IGNORE)


def test_resend_stops_out_of_guided_flight_and_into_a_stale_link() -> None:
    sp = RULES.new(Frame.NED, 1.0, 0.0, 0.0, 0.0, 0.0)
    assert RULES.due(vehicle(landed=mav.MAV_LANDED_STATE_ON_GROUND), sp, 0.2) == (None, Verdict.IGNORE)
    sp = RULES.new(Frame.NED, 1.0, 0.0, 0.0, 0.0, 0.0)
    stale = vehicle()
    stale.rx_at = -2.0
    assert RULES.due(stale, sp, 0.2) == (None, Verdict.WITHHOLD)


def test_a_stop_right_behind_the_backlog_when_the_link_returns() -> None:
    v = vehicle()
    assert RULES.stop_after_stale(v, 0.5) is None  # the link was never stale
    stop = RULES.stop_after_stale(v, 3.0)
    assert stop is not None and stop.zero and stop.frame == mav.MAV_FRAME_LOCAL_NED
    assert RULES.stop_after_stale(vehicle(landed=mav.MAV_LANDED_STATE_ON_GROUND), 3.0) is None
