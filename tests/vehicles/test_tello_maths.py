"""The Tello adapter's arithmetic (`antalate_lcm.vehicles.tello.maths`) and the shared altitude rule."""

from __future__ import annotations

import math
import re

import pytest

from antalate_lcm.vehicles.base import altitude_reached
from antalate_lcm.vehicles.tello import maths, telemetry
from antalate_lcm.vehicles.tello.params import Params


def test_altitude_reached_is_the_hlc_rule_with_float_slack_only() -> None:
    assert altitude_reached(1.14, 1.2, 0.95)  # 0.95 * 1.2 is 1.1399999...: exactly the threshold counts
    assert altitude_reached(1.2, 1.2, 1.0)
    assert not altitude_reached(1.1, 1.2, 0.95)  # a decimetre reading one step short: not reached
    assert not altitude_reached(1.199, 1.2, 1.0)


@pytest.mark.parametrize("target", [0.5, 0.8, 1.0, 1.2, 1.25, 1.5, 2.33, 3.0])
@pytest.mark.parametrize("fraction", [0.8, 0.95, 1.0])
def test_the_climb_never_stops_where_the_hlc_would_not_count_it(target: float, fraction: float) -> None:
    """On a decimetre grid, whatever reading ends the climb satisfies the HLC for any fraction <= 1."""
    readings = [dm / 10.0 for dm in range(0, 60)]
    done = [h for h in readings if maths.climb_done(h, target)]
    assert done, f"no decimetre reading ends a climb to {target} m"
    assert all(altitude_reached(h, target, fraction) for h in done)
    for h in readings:  # and the controller moves towards the band from anywhere outside it
        speed = maths.climb_speed(h, target, 1.0)
        if h in done:
            assert speed == 0.0
        else:
            assert abs(speed) >= maths.MIN_CLIMB_SPEED and (speed > 0) == (h < target)


def test_the_field_failure_climb_stopped_at_1_1_m() -> None:
    """The issue: a climb to 1.2 m ended at a reading of 1.1 m (within 0.1 m), below the HLC's 1.14 m."""
    assert not maths.climb_done(1.1, 1.2)
    assert maths.climb_speed(1.1, 1.2, 1.0) > 0.0
    assert maths.climb_done(1.2, 1.2) and maths.climb_done(1.3, 1.2)
    assert maths.climb_speed(1.4, 1.2, 1.0) < 0.0


def test_frames() -> None:
    assert maths.ground_to_ne(1.0, 0.0, 90.0) == pytest.approx((0.0, 1.0), abs=1e-12)  # yaw 0 faced east
    assert maths.ground_to_ne(0.0, 1.0, 90.0) == pytest.approx((-1.0, 0.0), abs=1e-12)  # its right: south
    assert maths.body_to_ground(1.0, 0.0, 90.0) == pytest.approx((0.0, 1.0), abs=1e-12)
    fwd, right = maths.ne_to_body(1.0, 0.0, 90.0)  # north, seen by a vehicle facing east: to its left
    assert (fwd, right) == pytest.approx((0.0, -1.0), abs=1e-12)
    for heading in (0.0, 37.0, 200.0):  # ne_to_body undoes ground_to_ne∘body_to_ground at yaw 0
        n, e = maths.ground_to_ne(0.3, -0.4, heading)
        assert maths.ne_to_body(n, e, heading) == pytest.approx((0.3, -0.4), abs=1e-12)


def test_dead_reckoning_trapezoid_and_gaps() -> None:
    assert maths.dead_reckon(1.0, 2.0, (0.0, 0.0), (1.0, -1.0), 0.1) == pytest.approx((1.05, 1.95))
    assert maths.dead_reckon(1.0, 2.0, (1.0, 1.0), (1.0, 1.0), 0.0) == (1.0, 2.0)
    assert maths.dead_reckon(1.0, 2.0, (1.0, 1.0), (1.0, 1.0), -0.1) == (1.0, 2.0)
    assert maths.dead_reckon(1.0, 2.0, (1.0, 1.0), (1.0, 1.0), 6.0) == (1.0, 2.0)  # a link loss: no guess


def test_rc_sticks_scale_and_direction() -> None:
    kw = {"max_speed": 2.0, "max_vertical_speed": 0.5, "max_yaw_rate": 90.0}
    assert maths.rc_sticks(1.0, -0.5, 0.25, 45.0, **kw) == (-25, 50, 50, 50)
    assert maths.rc_sticks(8.0, 4.0, -3.0, -500.0, **kw) == (50, 100, -100, -100)


def test_debounced_flag() -> None:
    d = maths.Debounced(0.5)
    assert not d.update(True, 0.0) and not d.value
    assert not d.update(False, 0.2)  # the blip is forgotten
    assert not d.update(True, 0.3) and not d.update(True, 0.7)
    assert d.update(True, 0.8) and d.value
    d.reset(False)
    assert not d.value


def test_rtl_leg_slows_down_near_home() -> None:
    vn, ve, dist = maths.rtl_leg(3.0, 4.0, (0.0, 0.0), speed=0.5, gain=1.0, min_speed=0.2)
    assert dist == pytest.approx(5.0) and math.hypot(vn, ve) == pytest.approx(0.5)
    assert (vn, ve) == pytest.approx((-0.3, -0.4))
    vn, ve, dist = maths.rtl_leg(0.3, 0.0, (0.0, 0.0), speed=0.5, gain=1.0, min_speed=0.2)
    assert vn == pytest.approx(-0.3) and dist == pytest.approx(0.3)
    assert maths.rtl_leg(0.0, 0.0, (0.0, 0.0), speed=0.5, gain=1.0, min_speed=0.2) == (0.0, 0.0, 0.0)


def test_a_state_packet_read_in_the_adapters_units() -> None:
    """`telemetry.read`: dm/s into north/east/down m/s through home_heading, height from h or tof."""
    p = Params()
    east = telemetry.read(
        {"yaw": 30, "vgx": 10, "vgy": 0, "vgz": -5, "h": 120, "bat": 80}, p, 90.0, telemetry.StateReading()
    )
    assert (east.vn, east.ve, east.vd) == pytest.approx(
        (0.0, 1.0, -0.5), abs=1e-9
    )  # x points east at heading 90
    assert (east.yaw, east.h_cm, east.height, east.battery) == (30.0, 120, 1.2, 80.0)
    partial = telemetry.read({"vgx": 0}, p, 90.0, east)  # a field the packet lacks keeps its value
    assert (partial.yaw, partial.h_cm, partial.battery) == (30.0, 120, 80.0) and partial.ve == 0.0
    tof = Params(altitude_source="tof")
    assert telemetry.read({"h": 0, "tof": 95}, tof, 0.0, telemetry.StateReading()).height == pytest.approx(
        0.85
    )
    assert telemetry.read({"h": 30, "tof": 6553}, tof, 0.0, telemetry.StateReading()).height == pytest.approx(
        0.3
    )
    body = Params(velocity_frame="body")
    turned = telemetry.read({"yaw": 90, "vgx": 10}, body, 0.0, telemetry.StateReading())
    assert (turned.vn, turned.ve) == pytest.approx((0.0, 1.0), abs=1e-9)  # forward, facing east


def _climb(check: maths.VelocityUnitCheck, scale: float, speed: float = 0.5) -> bool:
    """A climb of 1 m at `speed` seen at 10 Hz: height in decimetres, vgz as read assuming dm/s."""
    found = False
    for i in range(int(1.0 / speed * 10) + 1):
        t = i * 0.1
        height = round(min(speed * t, 1.0) * 10) / 10
        vd = -round(speed * scale) / 10.0  # the integer field divided by 10, as telemetry.read does
        found = check.update(height, vd, 0.0, 0.0, t) or found
    return found


def test_velocity_units_agree_with_the_height_when_dm_per_s() -> None:
    check = maths.VelocityUnitCheck()
    assert not _climb(check, 10.0)
    assert not check.problem and 0.5 <= check.ratio <= 2.0


@pytest.mark.parametrize(("scale", "factor"), [(100.0, r"x10\b"), (1.0, r"x0\.1\b")])
def test_velocity_units_other_than_dm_per_s_are_found_by_the_climb(scale: float, factor: str) -> None:
    check = maths.VelocityUnitCheck()
    assert _climb(check, scale, speed=1.0 if scale == 1.0 else 0.5)
    # found on the climb's first comparison: a factor of ten is beyond doubt at once
    assert re.search(factor, check.problem) and "dm/s" in check.problem, check.problem


def test_one_comparison_out_of_range_is_not_yet_a_unit_problem() -> None:
    """A fast take-off seen in a few rounded packets once gave one ratio out of range with the right unit."""
    check = maths.VelocityUnitCheck()
    for i in range(6):  # 0.5 m in 0.5 s, vgz reading three times the climb
        check.update(0.1 * i, -3.0, 0.0, 0.0, 0.1 * i)
    assert check.ratio > 2.0 and not check.problem
    assert not _climb(check, 10.0) or not check.problem  # the next comparison agrees: no problem
    assert not check.problem
    assert not check.update(2.0, 0.0, 0.0, 0.0, 100.0)  # said once, and it stays


def test_a_ground_speed_beyond_a_tello_is_a_unit_problem() -> None:
    check = maths.VelocityUnitCheck()
    assert not check.update(1.0, 0.0, 5.0, 0.0, 0.0)
    assert check.update(1.0, 0.0, 9.0, 0.0, 0.1)
    assert "beyond a Tello's 8 m/s" in check.problem


def test_a_vgz_that_stays_zero_leaves_the_unit_unchecked_not_wrong() -> None:
    check = maths.VelocityUnitCheck()
    assert _climb(check, 0.0)  # said once (a warning), but no problem
    assert not check.problem and "not checked" in check.unchecked
