"""The geofence: polygon checks, and agents flown by the pure filter that must stay inside or come back."""

from __future__ import annotations

import math

import pytest

from antalate_lcm.base.safety.filter import FilterParams, Policy, SafetyDecision, SafetyFilter
from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.base.safety.separation import SeparationParams

VMAX, DT = 5.0, 0.05
SQUARE = ((0.0, 0.0), (0.0, 40.0), (40.0, 40.0), (40.0, 0.0))
#: An L: concave, the notch at the north-east.
ELL = ((0.0, 0.0), (0.0, 40.0), (20.0, 40.0), (20.0, 20.0), (40.0, 20.0), (40.0, 0.0))


def make(fence: Geofence, outside: Policy = Policy.RETURN) -> SafetyFilter:
    sep = SeparationParams(radius=3.0, vertical=1.5, gamma=2.0, peer_speed=VMAX, stale_after=0.5)
    return SafetyFilter(FilterParams(sep, VMAX, 2.0, fence=fence, outside_fence=outside))


def fly(
    filt: SafetyFilter, start: tuple[float, float, float], wish: tuple[float, float, float], seconds: float
) -> tuple[list[float], str, list[tuple[tuple[float, ...], SafetyDecision]]]:
    pos = list(start)
    worst = ""
    track: list[tuple[tuple[float, ...], SafetyDecision]] = []
    for _ in range(int(seconds / DT)):
        d = filt.filter("a", tuple(pos), (0, 0, 0), wish, [])  # type: ignore[arg-type]
        for k in range(3):
            pos[k] += d.velocity[k] * DT
        track.append((tuple(pos), d))
        fence = filt.params.fence
        assert fence is not None
        worst = worst or fence.breach(*pos)
    return pos, worst, track


@pytest.mark.parametrize("polygon", [SQUARE, ELL, tuple(reversed(ELL))])
@pytest.mark.parametrize("heading", range(0, 360, 30))
def test_no_wish_leaves_the_polygon(polygon: tuple[tuple[float, float], ...], heading: int) -> None:
    fence = Geofence(polygon, floor=2.0, ceiling=30.0, margin=1.0)
    wish = (VMAX * math.cos(math.radians(heading)), VMAX * math.sin(math.radians(heading)), 0.0)
    pos, breach, track = fly(make(fence), (10.0, 10.0, 10.0), wish, 15.0)
    assert breach == ""
    assert fence.edge_distance(pos[0], pos[1]) >= 1.0 - 1e-6
    assert any(d.by == "fence" for _, d in track)


def test_floor_and_ceiling_hold() -> None:
    fence = Geofence(SQUARE, floor=2.0, ceiling=12.0, margin=0.5)
    pos, breach, _ = fly(make(fence), (20.0, 20.0, 10.0), (0.0, 0.0, 2.0), 10.0)
    assert breach == "" and pos[2] == pytest.approx(11.5, abs=0.01)
    pos, breach, _ = fly(make(fence), (20.0, 20.0, 10.0), (0.0, 0.0, -2.0), 10.0)
    assert breach == "" and pos[2] == pytest.approx(2.5, abs=0.01)


def test_landing_may_go_through_the_floor() -> None:
    fence = Geofence(SQUARE, floor=2.0, ceiling=12.0, margin=0.5)
    filt = make(fence)
    d = filt.filter("a", (20.0, 20.0, 2.5), (0, 0, 0), (0.0, 0.0, -1.0), [], landing=True)
    assert d.velocity == (0.0, 0.0, -1.0) and not d.modified
    d = filt.filter("a", (20.0, 20.0, 1.0), (0, 0, 0), (0.0, 0.0, -1.0), [], landing=True)
    assert d.velocity == (0.0, 0.0, -1.0) and d.reason == ""


def test_a_vehicle_found_outside_is_brought_back() -> None:
    fence = Geofence(ELL, floor=2.0, ceiling=30.0, margin=1.0)
    # In the notch of the L, outside: the way back is the nearest edge, and then it stays in.
    filt = make(fence)
    first = filt.filter("a", (30.0, 30.0, 10.0), (0, 0, 0), (VMAX, VMAX, 0.0), [])
    assert first.by == "fence" and "outside the fence polygon by 10.0 m" in first.reason
    assert first.velocity[0] < 0.0 or first.velocity[1] < 0.0
    pos, _, track = fly(filt, (30.0, 30.0, 10.0), (VMAX, VMAX, 0.0), 10.0)
    assert fence.breach(*pos) == ""
    assert track[-1][1].reason == ""


def test_above_the_ceiling_it_comes_down() -> None:
    fence = Geofence(SQUARE, floor=2.0, ceiling=12.0, margin=0.5)
    d = make(fence).filter("a", (20.0, 20.0, 15.0), (0, 0, 0), (0.0, 0.0, 1.0), [])
    assert d.velocity[2] < 0.0 and "above the fence ceiling" in d.reason


@pytest.mark.parametrize(("policy", "action"), [(Policy.LAND, "land"), (Policy.HOVER, "hover")])
def test_outside_policies(policy: Policy, action: str) -> None:
    fence = Geofence(SQUARE, floor=2.0, ceiling=12.0, margin=0.5)
    d = make(fence, policy).filter("a", (-5.0, 20.0, 10.0), (0, 0, 0), (1.0, 0.0, 0.0), [])
    assert d.action == action and d.velocity == (0.0, 0.0, 0.0) and d.by == "fence"
    assert "outside the fence polygon by 5.0 m" in d.reason


@pytest.mark.parametrize(
    ("polygon", "floor", "ceiling", "margin", "message"),
    [
        (((0.0, 0.0), (1.0, 1.0)), 0.0, 10.0, 1.0, "at least 3 vertices"),
        (((0.0, 0.0), (1.0, 1.0), (2.0, 2.0)), 0.0, 10.0, 1.0, "no area"),
        (((0.0, 0.0), (10.0, 10.0), (10.0, 0.0), (0.0, 5.0)), 0.0, 10.0, 1.0, "crosses itself"),
        (SQUARE, 10.0, 5.0, 1.0, "below its ceiling"),
        (SQUARE, 0.0, 1.0, 1.0, "leaves no room"),
        (SQUARE, 0.0, 10.0, -1.0, "margin must be >= 0"),
        (((0.0, math.nan), (1.0, 1.0), (2.0, 0.0)), 0.0, 10.0, 1.0, "not finite"),
    ],
)
def test_bad_fences_are_refused(polygon, floor, ceiling, margin, message) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=message):
        Geofence(polygon, floor, ceiling, margin)


def test_inside_polygon_even_odd() -> None:
    fence = Geofence(ELL, floor=0.0, ceiling=10.0, margin=0.0)
    assert fence.inside_polygon(10.0, 10.0) and fence.inside_polygon(30.0, 10.0)
    assert not fence.inside_polygon(30.0, 30.0) and not fence.inside_polygon(-1.0, 5.0)
