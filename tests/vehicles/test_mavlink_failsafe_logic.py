"""`antalate_lcm.vehicles.mavlink.failsafe`: a pilot's mode change or an ArduCopter failsafe (pure, no I/O)."""

from __future__ import annotations

import pytest

from antalate_lcm.vehicles import FlightMode
from antalate_lcm.vehicles.mavlink import failsafe as fs
from antalate_lcm.vehicles.mavlink.failsafe import (
    FailsafeTracker,
    classify,
    text_battery_level,
    text_failsafe,
)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("Fence Breached: Circle", fs.FENCE),
        ("Battery 1 is low 10.40V used 1200 mAh", fs.BATTERY),
        ("Battery 1 is critical 9.90V used 2400 mAh", fs.BATTERY),
        ("EKF variance", fs.EKF),
        ("EKF Failsafe: changed to LAND Mode", fs.EKF),
        ("GCS Failsafe", fs.GCS),
        ("GCS Failsafe - Disarming", fs.GCS),
        ("GCS Failsafe Cleared", ""),
        # ArduCopter 4.6.3 SITL's own words (SIM_RC_FAIL 1, FENCE_RADIUS, SIM_BATT_VOLTAGE)
        ("Radio Failsafe", fs.RC),
        ("Radio Failsafe - Continuing Landing", fs.RC),
        ("Radio Failsafe Cleared", ""),
        ("Circle fence breached", fs.FENCE),
        ("Fence breach cleared", ""),
        ("Battery Failsafe", fs.BATTERY),
        ("Battery 1 is low 10.80V used 401 mAh", fs.BATTERY),
        ("EKF Failsafe Cleared", ""),
        ("PreArm: Need Position Estimate", ""),
        ("Arming motors", ""),
    ],
)
def test_statustext(text: str, reason: str) -> None:
    assert text_failsafe(text) == reason


def test_battery_level_from_text() -> None:
    assert text_battery_level("Battery 1 is low 10.40V used 1200 mAh") == "low"
    assert text_battery_level("Battery 2 is critical 9.90V used 0 mAh") == "critical"
    assert text_battery_level("Fence Breached") == ""


def test_classify() -> None:
    assert classify("GUIDED", fs.FENCE) == (FlightMode.GUIDED, True, "")
    assert classify("RTL", fs.FENCE) == (FlightMode.RTL, True, fs.FENCE)
    assert classify("SMART_RTL", "") == (FlightMode.RTL, True, "")  # a pilot's RTL is still computer control
    assert classify("LAND", fs.EKF) == (FlightMode.LANDING, True, fs.EKF)
    assert classify("BRAKE", fs.FENCE) == (FlightMode.HOLD, True, fs.FENCE)
    assert classify("BRAKE", "") == (FlightMode.MANUAL, False, "")  # a pilot's brake
    assert classify("ALT_HOLD", fs.EKF) == (FlightMode.MANUAL, False, fs.EKF)  # FS_EKF_ACTION 2 needs a pilot
    assert classify("LOITER", "") == (FlightMode.MANUAL, False, "")


def test_tracker_attributes_an_uncommanded_mode_to_the_failsafe_around_it() -> None:
    t = FailsafeTracker()
    t.on_mode("GUIDED", 0.0, commanded=True)
    t.event(fs.text_failsafe("Fence Breached: Circle"), 10.0)  # the text comes first...
    t.on_mode("BRAKE", 10.8, commanded=False)  # ...the HEARTBEAT with the new mode up to a second later
    assert t.reason == fs.FENCE
    t.set_active(fs.FENCE, False, 12.0)  # the breach clears: the BRAKE is still the fence's
    assert t.reason == fs.FENCE
    t.on_mode("LAND", 20.0, commanded=True)  # the operator lands: ours, no failsafe
    assert t.reason == ""


def test_tracker_evidence_after_the_mode_and_the_window() -> None:
    t = FailsafeTracker()
    t.on_mode("RTL", 5.0, commanded=False)
    assert t.reason == ""  # nothing explains it yet
    t.set_active(fs.BATTERY, True, 6.0)  # BATTERY_STATUS at its stream rate, after the HEARTBEAT
    assert t.reason == fs.BATTERY
    t2 = FailsafeTracker()
    t2.event(fs.GCS, 0.0)
    t2.on_mode("RTL", 30.0, commanded=False)  # a stale GCS failsafe text explains nothing 30 s later
    assert t2.reason == ""
    t2.set_active(fs.FENCE, True, 40.0)  # and evidence long after the mode changed does not either
    assert t2.reason == ""


def test_tracker_priority_and_pilot_modes() -> None:
    t = FailsafeTracker()
    t.set_active(fs.EKF, True, 1.0)
    t.set_active(fs.FENCE, True, 1.0)
    t.on_mode("LAND", 1.5, commanded=False)
    assert t.reason == fs.FENCE  # the fence first: the operator must know the vehicle is outside
    t.on_mode("LOITER", 2.0, commanded=False)  # a pilot's switch during a failsafe is still a pilot's
    assert t.reason == ""
    t.on_mode("RTL", 3.0, commanded=True)  # our own RTL is never a failsafe
    assert t.reason == ""
