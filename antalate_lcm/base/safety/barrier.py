"""The one optimisation every safety constraint goes through: the velocity closest to the wish that
keeps every barrier constraint.

A control barrier function (Ames et al. 2017; Wang, Ames, Egerstedt 2017) turns "stay safe" into one
linear inequality on the commanded velocity per hazard, ``a . u <= b``. The filter then solves the
quadratic programme

    minimise |u - u_wish|^2  subject to  a_k . u <= b_k (every k),  |u_horizontal| <= h_max,  |u_up| <= v_max

in the three-dimensional velocity space (north, east, up). It is small (a handful of constraints near
any one agent), so it is solved here in pure Python by Dykstra's alternating projections (Boyle and
Dykstra 1986), which converge to the exact projection onto an intersection of convex sets, and then
made *exactly* feasible by one last step: when every ``b_k >= 0`` the zero velocity (hover) satisfies
them all, so scaling the result towards zero until no constraint is violated lands inside the safe
set whatever the iteration count. Safety therefore never depends on the solver's convergence, only
its optimality does.

When some ``b_k < 0`` (the agent is already inside a hazard: a peer closer than the radius, a fence
margin crossed) hover is not safe either; the best-effort result is returned with ``feasible``
False and the caller reports the conflict.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

Vec = tuple[float, float, float]

#: Dykstra sweeps; each sweep projects onto every constraint once. Enough for a few cm/s of optimality
#: with the handful of active constraints a swarm produces; feasibility does not depend on it.
_SWEEPS = 24
#: Working-set rounds: each adds the constraints the last projection still violated.
_ROUNDS = 4
#: Slack of the final feasibility check (m/s): below float noise of the products involved.
_EPS = 1e-9


@dataclass(frozen=True)
class Constraint:
    """``a . u <= b`` on the commanded velocity u (north, east, up), and what it protects from."""

    a: Vec
    b: float
    source: str  # "separation" or "fence"
    what: str  # the peer's name or the fence edge, for the operator


@dataclass(frozen=True)
class Solution:
    u: Vec
    #: Every constraint holds at `u` (always True when every b >= 0).
    feasible: bool
    #: The constraints `u` had to respect that the wish violated (their sources name who modified it).
    active: tuple[Constraint, ...]


def _dot(a: Vec, u: Vec) -> float:
    return a[0] * u[0] + a[1] * u[1] + a[2] * u[2]


def clamp_speed(u: Vec, h_max: float, v_max: float) -> Vec:
    """The velocity limits as a projection (the nearest point of the cylinder)."""
    n, e, up = u
    h = math.hypot(n, e)
    if h > h_max:
        s = h_max / h
        n, e = n * s, e * s
    return n, e, max(-v_max, min(v_max, up))


def _project_halfspace(u: Vec, c: Constraint) -> Vec:
    excess = _dot(c.a, u) - c.b
    if excess <= 0.0:
        return u
    norm2 = _dot(c.a, c.a)
    if norm2 == 0.0:
        return u
    k = excess / norm2
    return u[0] - k * c.a[0], u[1] - k * c.a[1], u[2] - k * c.a[2]


def _dykstra(u: Vec, sets: list[Constraint], h_max: float, v_max: float) -> Vec:
    """Dykstra's projection of `u` onto the half-spaces `sets` and the speed cylinder (the last set)."""
    m = len(sets) + 1
    x = u
    incr: list[Vec] = [(0.0, 0.0, 0.0)] * m
    for _ in range(_SWEEPS):
        moved = 0.0
        for i in range(m):
            p = incr[i]
            y = (x[0] + p[0], x[1] + p[1], x[2] + p[2])
            z = clamp_speed(y, h_max, v_max) if i == m - 1 else _project_halfspace(y, sets[i])
            incr[i] = (y[0] - z[0], y[1] - z[1], y[2] - z[2])
            moved += abs(z[0] - x[0]) + abs(z[1] - x[1]) + abs(z[2] - x[2])
            x = z
        if moved < 1e-6:
            break
    return x


def solve(
    wish: Vec, constraints: list[Constraint], h_max: float, v_max: float, *, vertical_weight: float = 1.0
) -> Solution:
    """The safe velocity nearest to `wish` (see the module docstring).

    `vertical_weight` w makes a change of vertical speed cost w^2 times a horizontal one
    (|u - wish|^2 measured with the vertical axis stretched by w): a swarm that must make room then
    steps aside rather than diving at the ground or climbing into the layer above.
    """
    if vertical_weight != 1.0:
        w = vertical_weight
        scaled = [Constraint((c.a[0], c.a[1], c.a[2] / w), c.b, c.source, c.what) for c in constraints]
        sol = solve((wish[0], wish[1], wish[2] * w), scaled, h_max, v_max * w)
        by_id = dict(zip(map(id, scaled), constraints, strict=True))
        u = sol.u
        return Solution((u[0], u[1], u[2] / w), sol.feasible, tuple(by_id[id(c)] for c in sol.active))
    u = clamp_speed(wish, h_max, v_max)
    violated = [c for c in constraints if _dot(c.a, u) > c.b + _EPS]
    if not violated:
        return Solution(u, True, ())
    # Dykstra over a working set (the violated constraints plus the speed cylinder), grown by any
    # constraint the result still violates: a handful of sets instead of every neighbour's.
    work = list(violated)
    held = {id(c) for c in work}
    x = u
    for _ in range(_ROUNDS):
        x = _dykstra(u, work, h_max, v_max)
        more = [c for c in constraints if id(c) not in held and _dot(c.a, x) > c.b + _EPS]
        if not more:
            break
        work.extend(more)
        held.update(id(c) for c in more)
    if all(c.b >= 0.0 for c in constraints):
        # Hover is safe: scale towards it until nothing is violated (exact feasibility).
        s = 1.0
        for c in constraints:
            ax = _dot(c.a, x)
            if ax > c.b:
                s = min(s, c.b / ax)
        x = (x[0] * s, x[1] * s, x[2] * s)
    feasible = all(_dot(c.a, x) <= c.b + 1e-6 for c in constraints)
    return Solution(x, feasible, tuple(violated))
