"""The swarm rule and its blending with the operator's direction, without any I/O."""

from __future__ import annotations

import json
import math

import pytest

from behaviors.dovrat_swarm.logic import (
    Detection,
    DetectionTracker,
    OperatorDirection,
    SwarmParams,
    parse_detection_payload,
    swarm_command,
    turn_rate,
)

P = SwarmParams(
    forward_speed=2.0, gentle_turn_rate=10.0, sharp_turn_rate=45.0, turn_direction=1, direction_weight=1.0
)


def _ground(heading: float, vx: float, vy: float) -> tuple[float, float]:
    """BODY (forward, right) → NED (north, east) for a heading in degrees."""
    h = math.radians(heading)
    return vx * math.cos(h) - vy * math.sin(h), vx * math.sin(h) + vy * math.cos(h)


def test_gentle_turn_while_a_peer_is_detected_sharp_while_none() -> None:
    assert turn_rate(True, P) == 10.0
    assert turn_rate(False, P) == 45.0
    left = SwarmParams(gentle_turn_rate=10.0, sharp_turn_rate=45.0, turn_direction=-1)
    assert (turn_rate(True, left), turn_rate(False, left)) == (-10.0, -45.0)  # both the same way


@pytest.mark.parametrize("detected", [True, False])
def test_without_a_direction_the_agent_flies_forward_and_turns(detected: bool) -> None:
    cmd = swarm_command(123.0, detected, None, P)
    assert (cmd.vx, cmd.vy) == (2.0, 0.0)
    assert cmd.yaw_rate == (10.0 if detected else 45.0)
    inactive = OperatorDirection(active=False, azimuth=90.0, speed=5.0)
    assert swarm_command(123.0, detected, inactive, P) == cmd


@pytest.mark.parametrize("detected", [True, False])
def test_direction_is_a_drift_added_to_the_swarm_rule(detected: bool) -> None:
    ahead = swarm_command(90.0, detected, OperatorDirection(True, 90.0, 3.0), P)
    assert ahead.vx == pytest.approx(5.0) and ahead.vy == pytest.approx(0.0)
    right = swarm_command(0.0, detected, OperatorDirection(True, 90.0, 3.0), P)
    assert right.vx == pytest.approx(2.0) and right.vy == pytest.approx(3.0)
    behind = swarm_command(270.0, detected, OperatorDirection(True, 90.0, 3.0), P)
    assert behind.vx == pytest.approx(-1.0) and behind.vy == pytest.approx(0.0, abs=1e-9)
    # the turning rule is untouched by the direction
    assert ahead.yaw_rate == right.yaw_rate == behind.yaw_rate == turn_rate(detected, P)


@pytest.mark.parametrize("heading", [0.0, 37.0, 150.0, 271.5, 359.0])
def test_every_agent_gets_the_same_ground_drift_whatever_its_heading(heading: float) -> None:
    # The relative motion of agents (what the swarm rule works on) is unchanged by the drift.
    direction = OperatorDirection(True, 60.0, 4.0)
    with_dir = swarm_command(heading, False, direction, P)
    without = swarm_command(heading, False, None, P)
    gn, ge = _ground(heading, with_dir.vx - without.vx, with_dir.vy - without.vy)
    assert gn == pytest.approx(4.0 * math.cos(math.radians(60.0)))
    assert ge == pytest.approx(4.0 * math.sin(math.radians(60.0)))


def test_direction_weight_speed_default_and_unknown_heading() -> None:
    half = SwarmParams(forward_speed=2.0, direction_weight=0.5)
    cmd = swarm_command(0.0, True, OperatorDirection(True, 0.0, 4.0), half)
    assert cmd.vx == pytest.approx(4.0)  # 2 + 0.5 * 4
    no_speed = swarm_command(0.0, True, OperatorDirection(True, 0.0, 0.0), P)
    assert no_speed.vx == pytest.approx(4.0)  # speed 0: the swarm's own forward speed
    ignored = SwarmParams(forward_speed=2.0, direction_weight=0.0)
    assert swarm_command(0.0, True, OperatorDirection(True, 0.0, 4.0), ignored).vx == 2.0
    assert swarm_command(None, True, OperatorDirection(True, 0.0, 4.0), P).vx == 2.0  # no heading, no drift


def test_max_speed_scales_the_blend_keeping_its_direction() -> None:
    capped = SwarmParams(forward_speed=2.0, direction_weight=1.0, max_speed=2.5)
    cmd = swarm_command(0.0, False, OperatorDirection(True, 90.0, 2.0), capped)
    assert math.hypot(cmd.vx, cmd.vy) == pytest.approx(2.5)
    assert math.atan2(cmd.vy, cmd.vx) == pytest.approx(math.atan2(2.0, 2.0))


def test_detection_expires_after_the_timeout() -> None:
    tracker = DetectionTracker(timeout=1.0)
    assert not tracker.detected(0.0)
    tracker.update(Detection(True, 2, 10.0, 5.0), now=10.0)
    assert tracker.detected(10.5) and tracker.current(10.5) == Detection(True, 2, 10.0, 5.0)
    assert not tracker.detected(11.01)  # stale "peer ahead" counts as none
    tracker.update(Detection(False), now=12.0)
    assert not tracker.detected(12.1)


def test_station_payload_parsing() -> None:
    good = json.dumps({"detected": True, "count": 2, "nearest_range": 12.5, "nearest_bearing": -8.0}).encode()
    assert parse_detection_payload(good) == Detection(True, 2, 12.5, -8.0)
    assert parse_detection_payload(b'{"detected": false}') == Detection(False, 0, 0.0, 0.0)
    for bad in (
        b"",
        b"not json",
        b"[1, 2]",
        b'{"count": 3}',
        b'{"detected": "yes"}',
        b'{"detected": true, "nearest_range": NaN}',
        b'{"detected": true, "count": "many"}',
        b"\xff\xfe",
    ):
        assert parse_detection_payload(bad) is None, bad


def test_non_finite_heading_or_direction_never_reaches_the_arithmetic() -> None:
    """Defence in depth (the node validates first): the rule alone stays finite on nonsense."""
    params = SwarmParams(forward_speed=2.0, sharp_turn_rate=40.0)
    for heading, direction in (
        (math.inf, OperatorDirection(True, 90.0, 1.0)),
        (0.0, OperatorDirection(True, math.inf, 1.0)),
        (0.0, OperatorDirection(True, 90.0, math.nan)),
        (math.nan, None),
    ):
        cmd = swarm_command(heading, False, direction, params)
        assert (cmd.vx, cmd.vy, cmd.yaw_rate) == (2.0, 0.0, 40.0)  # forward and turning, no drift
