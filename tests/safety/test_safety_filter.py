"""The separation and fence filter with known geometry: kinematic agents flown by the pure filter.

Two vehicle models: the single integrator the barrier's proof assumes (the minimum separation must be
the radius itself, to float noise), and the sim's first-order velocity lag (tau 0.5 s) with the filter
leading positions by the same tau (docs/safety.md states the margin measured here).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from antalate_lcm.base.safety.barrier import Constraint, solve
from antalate_lcm.base.safety.filter import FilterParams, Policy, SafetyFilter
from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.base.safety.separation import PeerView, SeparationParams

R = 3.0
VMAX = 5.0
DT = 0.05
#: The proven bound holds to float noise.
EXACT = 1e-6

Wish = Callable[[int, list[list[float]], float], tuple[float, float, float]]


def make_filter(
    *, gamma: float = 2.0, lead: float = 0.0, fence: Geofence | None = None, **extra: object
) -> SafetyFilter:
    sep = SeparationParams(radius=R, vertical=1.5, gamma=gamma, peer_speed=VMAX, stale_after=0.5, lead=lead)
    return SafetyFilter(FilterParams(sep, VMAX, 2.0, fence=fence, **extra))  # type: ignore[arg-type]


def fly(
    start: list[tuple[float, float, float]],
    wish: Wish,
    *,
    seconds: float = 12.0,
    tau: float = 0.0,
    filt: SafetyFilter | None = None,
    moving: Callable[[int], bool] = lambda i: True,
) -> tuple[float, list[list[float]]]:
    """Fly every agent for `seconds`; return the minimum pairwise 3-D distance and the final positions."""
    filt = filt or make_filter(lead=tau)
    pos = [list(p) for p in start]
    vel = [[0.0, 0.0, 0.0] for _ in pos]
    n = len(pos)
    best = math.inf
    t = 0.0
    while t < seconds:
        cmds = []
        for i in range(n):
            if not moving(i):
                cmds.append((0.0, 0.0, 0.0))
                continue
            peers = [
                PeerView(
                    str(j),
                    pos[j][0],
                    pos[j][1],
                    pos[j][2],
                    vel[j][0],
                    vel[j][1],
                    vel[j][2],
                    cooperative=moving(j),
                )
                for j in range(n)
                if j != i
            ]
            decision = filt.filter(str(i), tuple(pos[i]), tuple(vel[i]), wish(i, pos, t), peers)  # type: ignore[arg-type]
            cmds.append(decision.velocity)
        for i in range(n):
            for k in range(3):
                u = cmds[i][k]
                if tau > 0.0:
                    decay = math.exp(-DT / tau)
                    pos[i][k] += u * DT + (vel[i][k] - u) * tau * (1.0 - decay)
                    vel[i][k] = u + (vel[i][k] - u) * decay
                else:
                    pos[i][k] += u * DT
                    vel[i][k] = u
        for i in range(n):
            for j in range(i + 1, n):
                best = min(best, math.dist(pos[i], pos[j]))
        t += DT
    return best, pos


def toward(targets: list[tuple[float, float]], speed: float = VMAX) -> Wish:
    def wish(i: int, pos: list[list[float]], _t: float) -> tuple[float, float, float]:
        dn, de = targets[i][0] - pos[i][0], targets[i][1] - pos[i][1]
        d = math.hypot(dn, de)
        if d < 1e-9:
            return 0.0, 0.0, 0.0
        return dn / d * speed, de / d * speed, 0.0

    return wish


def to_centroid(i: int, pos: list[list[float]], _t: float) -> tuple[float, float, float]:
    n = len(pos)
    cn, ce = sum(p[0] for p in pos) / n, sum(p[1] for p in pos) / n
    dn, de = cn - pos[i][0], ce - pos[i][1]
    d = math.hypot(dn, de) or 1.0
    return dn / d * VMAX, de / d * VMAX, 0.0


@pytest.mark.parametrize("tau", [0.0, 0.5])
def test_head_on_pair_keeps_the_radius(tau: float) -> None:
    best, pos = fly([(0, 0, 10), (30, 0, 10)], toward([(30, 0), (0, 0)]), tau=tau)
    assert best >= R - EXACT
    assert best < R + 0.5  # they do come close: the filter is not a wall far away


def test_head_on_pair_get_past_each_other_with_a_nudge() -> None:
    # Exactly head-on the symmetric barrier stops both; a 1 cm offset lets them slide past.
    best, pos = fly([(0, 0, 10), (30, 0.01, 10)], toward([(30, 0), (0, 0)]), seconds=25)
    assert best >= R - EXACT
    assert pos[0][0] > 25 and pos[1][0] < 5


@pytest.mark.parametrize("tau", [0.0, 0.5])
def test_crossing_paths(tau: float) -> None:
    best, _ = fly([(-20, 0, 10), (0, -20, 10)], toward([(20, 0), (0, 20)]), tau=tau)
    assert best >= R - EXACT


@pytest.mark.parametrize("tau", [0.0, 0.5])
def test_overtaking(tau: float) -> None:
    def wish(i: int, pos: list[list[float]], _t: float) -> tuple[float, float, float]:
        return (VMAX if i == 0 else 1.0), 0.0, 0.0

    best, pos = fly([(0, 0, 10), (10, 0.2, 10)], wish, seconds=15, tau=tau)
    assert best >= R - EXACT
    assert pos[0][0] > pos[1][0]  # the faster one got past


@pytest.mark.parametrize("tau", [0.0, 0.5])
def test_dense_cluster_of_twenty_all_flying_to_the_centroid(tau: float) -> None:
    start = [((i // 5) * 7.0, (i % 5) * 7.0, 10.0) for i in range(20)]
    best, pos = fly(start, to_centroid, seconds=10, tau=tau)
    assert best >= R - EXACT
    spread = max(math.dist(p, q) for p in pos for q in pos)
    assert spread < 25.0  # they did gather (from 35 m across)


def test_a_stationary_peer_that_does_not_cooperate() -> None:
    best, pos = fly(
        [(0, 0, 10), (15, 0.3, 10)], toward([(30, 0), (15, 0)]), moving=lambda i: i == 0, seconds=15
    )
    assert best >= R - EXACT
    assert pos[1] == [15, 0.3, 10]


def test_vertical_separation_is_the_ellipsoid_half_height() -> None:
    # One above the other by 2 m (> the 1.5 m half-height): they may cross over each other.
    best, pos = fly([(0, 0, 10), (20, 0, 12)], toward([(20, 0), (0, 0)]), seconds=10)
    assert best >= 2.0 - EXACT
    assert pos[0][0] > 19 and pos[1][0] < 1


def test_a_stale_peer_occupies_a_growing_ball() -> None:
    filt = make_filter()
    # Heard 2 s ago at 14 m: it may now be anywhere within 10 m of there, 13 m with the radius.
    stale = PeerView("b", 14.0, 0.0, 10.0, age=2.0)
    d = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (VMAX, 0.0, 0.0), [stale])
    assert d.by == "separation"
    assert d.velocity[0] < 0.0  # backs away as fast as the ball grows
    fresh = PeerView("b", 14.0, 0.0, 10.0, age=0.0)
    d = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (VMAX, 0.0, 0.0), [fresh])
    assert d.by == "" and d.velocity == (VMAX, 0.0, 0.0)


def test_stale_reports_keep_a_pair_apart() -> None:
    # Each hears the other 0.3 s late (positions from 0.3 s ago): the inflation covers the delay.
    sep = SeparationParams(radius=R, vertical=1.5, gamma=2.0, peer_speed=VMAX, stale_after=0.5)
    filt = SafetyFilter(FilterParams(sep, VMAX, 2.0))
    history: list[list[tuple[float, float, float]]] = []
    pos = [[0.0, 0.0, 10.0], [30.0, 0.5, 10.0]]
    best = math.inf
    for step in range(400):
        history.append([tuple(p) for p in pos])  # type: ignore[misc]
        old = history[max(0, step - 6)]
        cmds = []
        for i in range(2):
            j = 1 - i
            peer = PeerView(str(j), old[j][0], old[j][1], old[j][2], age=0.3)
            target = 30.0 if i == 0 else 0.0
            wish = (math.copysign(VMAX, target - pos[i][0]), 0.0, 0.0)
            cmds.append(filt.filter(str(i), tuple(pos[i]), (0, 0, 0), wish, [peer]).velocity)  # type: ignore[arg-type]
        for i in range(2):
            for k in range(3):
                pos[i][k] += cmds[i][k] * DT
        best = min(best, math.dist(pos[0], pos[1]))
    assert best >= R - EXACT


@pytest.mark.parametrize(
    ("policy", "velocity", "action"),
    [
        (Policy.HOVER, (0.0, 0.0, 0.0), "hover"),
        (Policy.CONTINUE, (VMAX, 0.0, 0.0), ""),
        (Policy.LAND, (VMAX, 0.0, 0.0), "land"),
    ],
)
def test_no_peer_information_says_so_and_follows_the_policy(
    policy: Policy, velocity: tuple[float, float, float], action: str
) -> None:
    filt = make_filter(min_peers=2, no_peers=policy)
    peers = [PeerView("b", 50.0, 0.0, 10.0), PeerView("c", 60.0, 0.0, 10.0, age=5.0)]
    d = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (VMAX, 0.0, 0.0), peers)
    assert d.action == action
    assert d.velocity == velocity
    assert "no peer information: 1 fresh peer(s) of min_peers 2" in d.reason
    ok = filt.filter(
        "a", (0.0, 0.0, 10.0), (0, 0, 0), (VMAX, 0.0, 0.0), peers[:1] + [PeerView("c", 60, 0, 10)]
    )
    assert ok.action == "" and ok.reason == ""


def test_reports_the_nearest_peer_and_its_distance() -> None:
    filt = make_filter()
    peers = [PeerView("far", 40.0, 0.0, 10.0), PeerView("near", 0.0, 4.0, 13.0)]
    d = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (0.0, 0.0, 0.0), peers)
    assert d.nearest == "near" and d.nearest_distance == pytest.approx(5.0)
    lonely = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (1.0, 0.0, 0.0), [])
    assert lonely.nearest == "" and math.isinf(lonely.nearest_distance) and not lonely.modified


def test_inside_the_radius_it_backs_off_and_says_so() -> None:
    filt = make_filter()
    d = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (1.0, 0.0, 0.0), [PeerView("b", 1.0, 0.0, 10.0)])
    assert d.velocity[0] < 0.0
    assert d.by == "separation"


def test_coincident_agents_part_in_opposite_directions() -> None:
    filt = make_filter()
    a = filt.filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (0, 0, 0), [PeerView("b", 0.0, 0.0, 10.0)])
    b = filt.filter("b", (0.0, 0.0, 10.0), (0, 0, 0), (0, 0, 0), [PeerView("a", 0.0, 0.0, 10.0)])
    assert a.velocity[0] > 0.0 > b.velocity[0]


# ---------------------------------------------------------------- the proof, as a property


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-12, 12),
            st.floats(-12, 12),
            st.floats(8, 12),
            st.floats(-VMAX, VMAX),
            st.floats(-VMAX, VMAX),
            st.floats(-2, 2),
        ),
        min_size=2,
        max_size=7,
    )
)
def test_one_step_never_breaks_separation(agents: list[tuple[float, ...]]) -> None:
    """From any separated configuration, any wishes, one synchronous step keeps every pair apart."""
    sep = SeparationParams(radius=R, vertical=1.5, gamma=2.0, peer_speed=VMAX, stale_after=0.5)
    s = sep.stretch

    def dist(p: tuple[float, ...], q: tuple[float, ...]) -> float:
        return math.sqrt((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 + ((p[2] - q[2]) * s) ** 2)

    for i in range(len(agents)):
        for j in range(i):
            if dist(agents[i], agents[j]) < R:
                return  # not a separated start
    filt = SafetyFilter(FilterParams(sep, VMAX, 2.0))
    new = []
    for i, a in enumerate(agents):
        peers = [PeerView(str(j), b[0], b[1], b[2]) for j, b in enumerate(agents) if j != i]
        u = filt.filter(str(i), a[:3], (0, 0, 0), a[3:], peers).velocity  # type: ignore[arg-type]
        new.append(tuple(a[k] + u[k] * DT for k in range(3)))
    for i in range(len(new)):
        for j in range(i):
            assert dist(new[i], new[j]) >= R - EXACT


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(0, 3)), max_size=6),
    st.tuples(st.floats(-9, 9), st.floats(-9, 9), st.floats(-3, 3)),
)
def test_solver_result_is_feasible_and_within_the_limits(
    planes: list[tuple[float, float, float, float]], wish: tuple[float, float, float]
) -> None:
    constraints = [Constraint(p[:3], p[3], "separation", "x") for p in planes]
    sol = solve(wish, constraints, VMAX, 2.0)
    assert sol.feasible
    assert math.hypot(sol.u[0], sol.u[1]) <= VMAX + 1e-9 and abs(sol.u[2]) <= 2.0 + 1e-9
    for c in constraints:
        assert c.a[0] * sol.u[0] + c.a[1] * sol.u[1] + c.a[2] * sol.u[2] <= c.b + 1e-6


def test_solver_leaves_a_safe_wish_alone_and_projects_onto_one_plane() -> None:
    plane = Constraint((1.0, 0.0, 0.0), 2.0, "fence", "edge 0")
    assert solve((1.0, 1.0, 0.0), [plane], VMAX, 2.0).u == (1.0, 1.0, 0.0)
    sol = solve((4.0, 1.0, 0.0), [plane], VMAX, 2.0)
    assert sol.u == pytest.approx((2.0, 1.0, 0.0), abs=1e-6)
    assert sol.active == (plane,)


def test_invalid_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="radius"):
        SeparationParams(radius=0.0, vertical=1.0, gamma=1.0, peer_speed=1.0, stale_after=1.0)
    with pytest.raises(ValueError, match="gamma"):
        SeparationParams(radius=1.0, vertical=1.0, gamma=math.nan, peer_speed=1.0, stale_after=1.0)
    with pytest.raises(ValueError, match="lead"):
        SeparationParams(radius=1.0, vertical=1.0, gamma=1.0, peer_speed=1.0, stale_after=1.0, lead=-1)


def test_boxed_in_inside_the_margin_it_says_it_cannot_keep_separation() -> None:
    """Four peers 1 m away on every side (radius 3 m): no velocity keeps every barrier, so the filter
    backs off as best it can and says so, naming the pair (the e2e take-off test's squeeze, exactly)."""
    box = [PeerView(n, dn, de, 10.0) for n, dn, de in (("b", 1, 0), ("c", -1, 0), ("d", 0, 1), ("e", 0, -1))]
    d = make_filter().filter("a", (0.0, 0.0, 10.0), (0, 0, 0), (VMAX, 0.0, 0.0), box)
    assert d.by == "separation" and d.nearest_distance == 1.0
    assert d.reason.startswith("cannot keep separation (") and "inside the margin" in d.reason
