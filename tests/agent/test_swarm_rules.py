"""The canonical swarm rules and the simulated peer sensor, pure (behaviors/swarm_rules/logic.py,
behaviors/peer_sensor/logic.py): no bus, no clock."""

from __future__ import annotations

import math
import random

import pytest

from behaviors.peer_sensor.logic import Body, SensorParams, scan
from behaviors.swarm_rules.logic import (
    DispersionParams,
    FlockingParams,
    GatheringParams,
    Neighbour,
    clamp,
    dispersion,
    flocking,
    gathering,
    radius,
    separate,
)


def test_clamp_scales_down_only() -> None:
    assert clamp((3.0, 4.0), 10.0) == (3.0, 4.0)
    assert clamp((3.0, 4.0), 1.0) == pytest.approx((0.6, 0.8))
    assert clamp((0.0, 0.0), 1.0) == (0.0, 0.0)


def test_radius_is_the_largest_distance_from_the_centroid() -> None:
    assert radius([(0.0, 0.0)]) == 0.0
    assert radius([(0.0, 0.0), (0.0, 4.0)]) == pytest.approx(2.0)
    assert radius([(0.0, 0.0), (0.0, 2.0), (0.0, 10.0)]) == pytest.approx(6.0)


def test_separation_limits_the_closing_speed_to_the_gap() -> None:
    ahead = [Neighbour(5.0, 0.0)]  # 5 m north
    # far: gain x (5 - 3 - 0.3) = 0.85 m/s allowed towards it; the sideways part is kept
    assert separate((2.0, 1.0), ahead, 3.0, 0.3, 0.5) == pytest.approx((0.85, 1.0))
    # away from it: untouched
    assert separate((-2.0, 0.0), ahead, 3.0, 0.3, 0.5) == (-2.0, 0.0)
    # inside separation + margin: pushed away even when asked to stand still
    vn, ve = separate((0.0, 0.0), [Neighbour(2.0, 0.0)], 3.0, 0.3, 0.5)
    assert vn == pytest.approx(-0.65) and ve == pytest.approx(0.0)
    # on top of each other: a fixed way out, never a division by zero
    vn, ve = separate((0.0, 0.0), [Neighbour(0.0, 0.0)], 3.0, 0.3, 0.5)
    assert math.isfinite(vn) and vn < 0


def test_gathering_goes_to_the_centroid_and_stops_once_gathered() -> None:
    p = GatheringParams(jitter=0.0)
    vn, ve = gathering([Neighbour(20.0, 0.0), Neighbour(20.0, 10.0)], p)
    assert vn > 0 and ve > 0 and math.hypot(vn, ve) == pytest.approx(p.speed)
    # within stop_radius: nothing more than what separation asks
    assert gathering([Neighbour(3.5, 0.0), Neighbour(0.0, 3.5)], p) == (0.0, 0.0)
    assert gathering([], p) == (0.0, 0.0)


def test_gathering_never_closes_on_a_peer_inside_the_separation() -> None:
    p = GatheringParams(jitter=1.0, stop_radius=0.0)
    near = [Neighbour(3.1, 0.0), Neighbour(0.5, -3.1), Neighbour(0.2, 20.0)]  # two close, 80 deg apart
    for angle in range(0, 360, 15):
        jitter = (math.cos(math.radians(angle)), math.sin(math.radians(angle)))
        vn, ve = gathering(near, p, jitter)
        for nb in near[:2]:
            closing = (vn * nb.north + ve * nb.east) / nb.distance
            # alternating projections: within 1 mm/s of every limit after the passes
            assert closing <= p.separation_gain * (nb.distance - p.separation - p.margin) + 1e-3


def test_flocking_aligns_with_the_neighbours_at_the_cruise_speed() -> None:
    p = FlockingParams(speed=2.0, heading=90.0)
    far = [Neighbour(0.0, 50.0, 1.0, 0.0), Neighbour(50.0, 0.0, 1.0, 0.0)]
    vn, ve = flocking((0.0, 1.0), far, p)  # flying east, the flock north: turns mostly north
    assert math.hypot(vn, ve) == pytest.approx(2.0)
    assert vn > ve > 0
    # nobody moves: the initial heading (90 = east)
    vn, ve = flocking((0.0, 0.0), [Neighbour(30.0, 0.0)], p)
    assert vn == pytest.approx(2.0 * p.cohesion * 30.0 / math.hypot(p.cohesion * 30.0, 0.0), abs=1e-6)
    vn, ve = flocking((0.0, 0.0), [], p)
    assert (vn, ve) == pytest.approx((0.0, 2.0), abs=1e-9)


def test_flocking_ignores_peers_outside_the_neighbourhood_but_still_keeps_clear() -> None:
    p = FlockingParams(neighbourhood=10.0)
    only_far = [Neighbour(0.0, 50.0, 0.0, -1.5)]
    assert flocking((1.5, 0.0), only_far, p) == pytest.approx((1.5, 0.0))
    vn, _ = flocking((1.5, 0.0), [Neighbour(3.2, 0.0, 0.0, 0.0)], FlockingParams(alignment=0.0, cohesion=0.0))
    assert vn <= 0.0  # heading at a peer 3.2 m ahead: held back (3.2 < 3 + 0.5 margin)


def test_dispersion_spreads_and_stays_in_its_area() -> None:
    p = DispersionParams(spacing=10.0, area_radius=30.0)
    vn, ve = dispersion((0.0, 0.0), [Neighbour(4.0, 0.0)], p)
    assert vn < 0 and ve == pytest.approx(0.0)  # away from the peer
    assert dispersion((0.0, 0.0), [Neighbour(12.0, 0.0)], p) == (0.0, 0.0)  # spread enough: still
    vn, ve = dispersion((-35.0, 0.0), [], p)  # 35 m north of home, outside the 30 m area
    assert vn < 0 and math.hypot(vn, ve) == pytest.approx(p.speed)
    # at the edge (29 m north), a peer south of it would push it out: held at the edge instead
    vn, _ = dispersion((-29.0, 0.0), [Neighbour(-4.0, 0.0)], p)
    assert vn <= 1e-9


@pytest.mark.parametrize("rule", ["gathering", "flocking", "dispersion"])
def test_every_rule_keeps_its_output_finite_on_degenerate_input(rule: str) -> None:
    stacked = [Neighbour(0.0, 0.0, 0.0, 0.0)] * 3
    out = {
        "gathering": lambda: gathering(stacked, GatheringParams()),
        "flocking": lambda: flocking((0.0, 0.0), stacked, FlockingParams()),
        "dispersion": lambda: dispersion((0.0, 0.0), stacked, DispersionParams()),
    }[rule]()
    assert all(math.isfinite(v) for v in out)


# ---------------------------------------------------------------------------------------------- sensor
ME = Body("me", 0.0, 0.0, 10.0, 0.0, 0.0, heading=90.0)  # facing east


def test_scan_gives_range_bearing_and_elevation_relative_to_the_heading() -> None:
    others = [Body("a", 0.0, 10.0, 10.0), Body("b", 10.0, 0.0, 20.0)]
    got = scan(ME, others, SensorParams(identities=True), random.Random(1))
    assert [s.id for s in got] == ["a", "b"]  # nearest first
    a, b = got
    assert a.range == pytest.approx(10.0) and a.bearing == pytest.approx(0.0) and a.elevation == 0.0
    assert b.range == pytest.approx(math.hypot(10.0, 10.0))
    assert b.bearing == pytest.approx(-90.0)  # north is on the left of an east-facing agent
    assert b.elevation == pytest.approx(45.0)


def test_scan_keeps_to_its_range_and_field_of_view_and_hides_names() -> None:
    others = [Body("ahead", 0.0, 10.0, 10.0), Body("behind", 0.0, -10.0, 10.0), Body("far", 0.0, 50.0, 10.0)]
    got = scan(ME, others, SensorParams(max_range=20.0, fov=90.0), random.Random(1))
    assert len(got) == 1 and got[0].id == "" and got[0].range == pytest.approx(10.0)


def test_scan_relative_velocity_is_in_the_body_frame() -> None:
    me = Body("me", 0.0, 0.0, 0.0, vn=0.0, ve=1.0, heading=90.0)
    other = Body("a", 0.0, 5.0, 0.0, vn=2.0, ve=1.0)  # the same eastward speed, plus 2 m/s north
    (s,) = scan(me, [other], SensorParams(velocity=True), random.Random(1))
    assert s.rel_forward == pytest.approx(0.0, abs=1e-9) and s.rel_right == pytest.approx(-2.0)
    (s,) = scan(me, [other], SensorParams(), random.Random(1))
    assert (s.rel_forward, s.rel_right) == (0.0, 0.0)


def test_scan_noise_and_dropout_follow_their_knobs() -> None:
    others = [Body(f"p{i}", 0.0, 10.0, 10.0) for i in range(2000)]
    got = scan(ME, others, SensorParams(range_noise=0.5, bearing_noise=2.0, dropout=0.25), random.Random(7))
    assert 0.70 < len(got) / len(others) < 0.80
    ranges = [s.range for s in got]
    mean = sum(ranges) / len(ranges)
    std = math.sqrt(sum((r - mean) ** 2 for r in ranges) / len(ranges))
    assert mean == pytest.approx(10.0, abs=0.05) and std == pytest.approx(0.5, abs=0.05)
    assert all(-180.0 <= s.bearing < 180.0 for s in got)
    again = scan(ME, others, SensorParams(range_noise=0.5, bearing_noise=2.0, dropout=0.25), random.Random(7))
    assert again == got  # seeded: repeatable
