"""The Crazyflie adapter's pure parts: frame mapping, set-point building, log decoding, parameters."""

from __future__ import annotations

import math
from typing import Any

import pytest

from antalate_lcm.base.geo import distance_bearing
from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.crazyflie import CrazyflieAdapter
from antalate_lcm.vehicles.crazyflie.frames import LocalFrame
from antalate_lcm.vehicles.crazyflie.setpoints import MIN_HEIGHT, build_setpoint, is_zero, next_height
from antalate_lcm.vehicles.crazyflie.telemetry import (
    LOG_BLOCKS,
    LOG_MAX_BYTES,
    Reading,
    SupervisorFlags,
    apply_log,
    battery_warning,
    block_size,
    estimator_problem,
)

LAT, LON = 32.7767, 35.0231


# ---------------------------------------------------------------- frames
@pytest.mark.parametrize(
    ("heading", "x", "y", "north", "east"),
    [
        (0.0, 1.0, 0.0, 1.0, 0.0),  # +x north: +y (anticlockwise) is west
        (0.0, 0.0, 1.0, 0.0, -1.0),
        (90.0, 1.0, 0.0, 0.0, 1.0),  # +x east: +y is north
        (90.0, 0.0, 1.0, 1.0, 0.0),
        (180.0, 2.0, 0.0, -2.0, 0.0),
    ],
)
def test_local_vectors_map_to_north_east(
    heading: float, x: float, y: float, north: float, east: float
) -> None:
    frame = LocalFrame(LAT, LON, heading)
    n, e = frame.to_ne(x, y)
    assert (n, e) == pytest.approx((north, east), abs=1e-12)
    assert frame.from_ne(n, e) == pytest.approx((x, y), abs=1e-12)


@pytest.mark.parametrize(
    ("heading", "yaw", "compass"),
    [(0.0, 0.0, 0.0), (0.0, 90.0, 270.0), (90.0, 0.0, 90.0), (90.0, -90.0, 180.0), (30.0, 45.0, 345.0)],
)
def test_yaw_counter_clockwise_becomes_a_compass_heading(heading: float, yaw: float, compass: float) -> None:
    assert LocalFrame(LAT, LON, heading).heading(yaw) == pytest.approx(compass)


def test_position_is_placed_on_wgs84_at_the_right_distance_and_bearing() -> None:
    frame = LocalFrame(LAT, LON, 60.0)
    lat, lon = frame.to_wgs84(3.0, 4.0)
    dist, bearing = distance_bearing(LAT, LON, lat, lon)
    assert dist == pytest.approx(5.0, abs=1e-6)
    # +x at 60 deg, +y at -30 deg: (3, 4) is atan2(4, 3) = 53.13 deg anticlockwise of +x
    assert bearing == pytest.approx((60.0 - math.degrees(math.atan2(4.0, 3.0))) % 360.0, abs=1e-6)
    assert frame.from_wgs84(lat, lon) == pytest.approx((3.0, 4.0), abs=1e-6)


def test_velocity_up_is_negative_down() -> None:
    assert LocalFrame(LAT, LON, 0.0).velocity_ned(0.0, 0.0, 0.4) == pytest.approx((0.0, 0.0, -0.4))


# ---------------------------------------------------------------- set-points
def test_ned_command_becomes_a_world_setpoint_in_the_local_frame() -> None:
    frame = LocalFrame(LAT, LON, 90.0)  # +x east, +y north
    sp = build_setpoint(1.0, 0.5, -0.2, 30.0, Frame.NED, frame, height=1.0)
    assert sp.kind == "world"
    # north 1.0 is +y, east 0.5 is +x; 0.2 m/s up; 30 deg/s clockwise is -30 anticlockwise
    assert sp.values == pytest.approx((0.5, 1.0, 0.2, -30.0))


def test_body_command_becomes_a_hover_setpoint_left_positive() -> None:
    sp = build_setpoint(0.8, 0.3, 0.0, -10.0, Frame.BODY, LocalFrame(LAT, LON, 0.0), height=1.2)
    assert sp.kind == "hover"
    assert sp.values == pytest.approx((0.8, -0.3, 10.0, 1.2))


def test_body_height_never_below_the_floor_margin() -> None:
    sp = build_setpoint(0.0, 0.0, 1.0, 0.0, Frame.BODY, LocalFrame(LAT, LON, 0.0), height=0.0)
    assert sp.values[3] == MIN_HEIGHT
    assert next_height(0.2, 5.0, 0.5) == MIN_HEIGHT


def test_body_height_integrates_the_vertical_velocity() -> None:
    h = 1.0
    for _ in range(10):
        h = next_height(h, -0.3, 0.1)  # climbing at 0.3 m/s for 1 s
    assert h == pytest.approx(1.3)
    assert next_height(1.0, -0.3, 5.0) == 1.0  # a stalled thread integrates nothing
    assert next_height(1.0, -0.3, -0.1) == 1.0


def test_non_finite_command_is_refused() -> None:
    with pytest.raises(ValueError, match="non-finite"):
        build_setpoint(math.nan, 0.0, 0.0, 0.0, Frame.NED, LocalFrame(LAT, LON, 0.0), height=1.0)


def test_zero_is_below_a_millimetre_per_second() -> None:
    assert is_zero(0.0, 0.0005, 0.0, 0.0)
    assert not is_zero(0.0, 0.0, 0.0, 1.0)


# ---------------------------------------------------------------- log decoding
def test_every_log_block_fits_one_packet() -> None:
    types = {
        "stateEstimate": "float",
        "kalman": "float",
        "pm.vbat": "float",
        "pm.state": "int8_t",
        "pm.batteryLevel": "uint8_t",
        "supervisor.info": "uint16_t",
    }

    def ctype(name: str) -> str:
        return types.get(name) or types[name.split(".")[0]]

    for names in LOG_BLOCKS.values():
        assert block_size([ctype(n) for n in names]) <= LOG_MAX_BYTES


def test_log_values_fill_the_reading() -> None:
    r = apply_log(
        Reading(),
        {
            "stateEstimate.x": 1.5,
            "stateEstimate.y": -2.0,
            "stateEstimate.z": 0.7,
            "pm.vbat": 3.9,
            "pm.batteryLevel": 60,
            "pm.state": 0,
            "supervisor.info": 0b11010,
            "unknown.var": 3,
        },
    )
    assert (r.x, r.y, r.z, r.vbat, r.battery_level) == (1.5, -2.0, 0.7, 3.9, 60)
    assert r.has_pose
    assert r.flags.armed and r.flags.can_fly and r.flags.flying and not r.flags.locked


def test_nan_position_keeps_the_last_finite_one_but_nan_variance_is_not_converged() -> None:
    r = apply_log(
        Reading(),
        {
            "stateEstimate.x": 1.0,
            "stateEstimate.y": 1.0,
            "stateEstimate.z": 1.0,
            "kalman.varPX": 1e-5,
            "kalman.varPY": 1e-5,
            "kalman.varPZ": 1e-5,
        },
    )
    r = apply_log(r, {"stateEstimate.x": math.nan, "kalman.varPX": math.nan})
    assert r.x == 1.0
    assert "varX nan" in estimator_problem(r, 0.001)


def test_estimator_check_names_every_axis_over_the_limit() -> None:
    r = apply_log(
        Reading(),
        {
            "stateEstimate.x": 0.0,
            "stateEstimate.y": 0.0,
            "stateEstimate.z": 0.0,
            "kalman.varPX": 0.5,
            "kalman.varPY": 1e-5,
            "kalman.varPZ": 0.2,
        },
    )
    problem = estimator_problem(r, 0.001)
    assert (
        "not converged" in problem
        and "varX 0.5" in problem
        and "varZ 0.2" in problem
        and "varY" not in problem
    )
    ok = apply_log(r, {"kalman.varPX": 1e-4, "kalman.varPZ": 1e-4})
    assert estimator_problem(ok, 0.001) == ""
    assert "no position estimate" in estimator_problem(Reading(), 0.001)


@pytest.mark.parametrize(
    ("info", "words"), [(1 << 6, "locked"), (1 << 7, "crash"), (1 << 5, "tumbled"), (1, "")]
)
def test_supervisor_blockers_say_what_to_do(info: int, words: str) -> None:
    blocker = SupervisorFlags.from_info(info).arm_blocker()
    assert (words in blocker) if words else blocker == ""


def test_pm_state_low_power_is_the_vehicle_battery_warning() -> None:
    assert "lowPower" in battery_warning(3)
    assert "shutDown" in battery_warning(4)
    assert battery_warning(0) == battery_warning(1) == ""


# ---------------------------------------------------------------- parameters
def test_defaults_validate_and_the_adapter_is_built_without_io() -> None:
    ap = CrazyflieAdapter({"uri": "udp://127.0.0.1:19850"})
    state = ap.state()
    assert not state.connected and state.link_age == math.inf


@pytest.mark.parametrize(
    ("params", "words"),
    [
        ({"uri": "http://cf"}, "cflib URI"),
        ({"velocity_hold": 0.6}, "velocity_hold"),  # past the firmware watchdog's 0.5 s
        ({"velocity_hold": 0.05}, "two set-point periods"),
        ({"link_stale_after": 0.1}, "three log periods"),
        ({"origin_heading": "90"}, "origin_heading"),
        ({"orign_lat": 1.0}, "orign_lat"),
        ({"cells": 0}, "cells"),
    ],
)
def test_bad_parameters_name_the_key(params: dict[str, object], words: str) -> None:
    with pytest.raises(ValueError, match=words):
        CrazyflieAdapter(params)


@pytest.mark.parametrize(
    ("table", "key", "phrase"),
    [
        ('uri = "http://x"', "uri", "cflib URI"),
        ("origin_heading = '90'", "origin_heading", "valid "),
        ("cells = true", "cells", "valid "),
        ("no_such_key = 1", "no_such_key", "Extra inputs"),
    ],
)
def test_config_loader_names_the_bad_autopilot_param(
    tmp_path: Any, table: str, key: str, phrase: str
) -> None:
    """The plan applies the adapter's params_model before anything starts (one line, the key)."""
    from antalate_lcm.agent.plan import load_plan
    from antalate_lcm.base.errors import ConfigError

    path = tmp_path / "cf.toml"
    path.write_text(f'[hlc]\nautopilot = "crazyflie"\n[hlc.autopilot_params]\n{table}\n')
    with pytest.raises(ConfigError) as info:
        load_plan(path)
    assert info.value.key == f"hlc.autopilot_params.{key}" and phrase in info.value.expected, str(info.value)
    assert "\n" not in str(info.value)
