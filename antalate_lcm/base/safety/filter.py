"""The safety filter: what the HLC sends instead of a behavior's velocity when it would lose separation
or leave the fence (docs/safety.md). Pure: positions and the wish in, a decision out.

One call per velocity set-point: `SafetyFilter.filter` takes the agent's own position and velocity,
the peers it knows (`PeerView`, from the swarm's telemetry) and the wished velocity (north, east, up),
and returns a `SafetyDecision`: the velocity to send, whether (and by what) it was modified, the
nearest peer and its distance, and what to do when the constraints cannot be met or nothing is known
of the peers (`Policy`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from antalate_lcm.base.safety.barrier import Constraint, Solution, Vec, clamp_speed, solve
from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.base.safety.separation import PeerView, SeparationParams, peer_constraints


class Policy(enum.Enum):
    """What the HLC does when the filter cannot keep its promise (no peer information, out of the fence)."""

    HOVER = "hover"  # stop where it is (velocity zero), keep filtering
    CONTINUE = "continue"  # fly the (filtered) wish anyway
    LAND = "land"  # land where it is
    RETURN = "return"  # (fence only) fly back inside, then carry on


@dataclass(frozen=True)
class SafetyDecision:
    velocity: Vec  # north, east, up (m/s) to send
    #: Who changed the wish: "" (nobody), "separation", "fence", or "separation+fence".
    by: str
    nearest: str  # the nearest peer's name, "" when none is known
    nearest_distance: float  # m (3-D, to its reported position); inf when none is known
    #: The policy's verdict when the filter cannot hold: LAND or HOVER or "" (fly `velocity`).
    action: str = ""
    #: Why (for the log and the operator): the conflict, the breach, "no peer information".
    reason: str = ""

    @property
    def modified(self) -> bool:
        return bool(self.by)


@dataclass(frozen=True)
class FilterParams:
    separation: SeparationParams
    max_horizontal: float  # m/s: our own limit (the HLC's max_horizontal_speed)
    max_vertical: float  # m/s
    fence: Geofence | None = None
    #: Fewer fresh peers than this (age <= stale_after) is "no peer information".
    min_peers: int = 0
    no_peers: Policy = Policy.HOVER
    outside_fence: Policy = Policy.RETURN
    #: How much more a change of vertical speed costs than a horizontal one (`barrier.solve`).
    vertical_weight: float = 4.0


class SafetyFilter:
    """Stateless apart from its parameters; one per agent."""

    def __init__(self, params: FilterParams) -> None:
        self.params = params
        sep = params.separation
        #: Beyond this margin over the radius a barrier allows more than our full speed: skip it.
        self._reach = 2.0 * math.hypot(params.max_horizontal, params.max_vertical) / sep.gamma

    @property
    def horizon(self) -> float:
        """How far (m, from this agent's led position) a fresh peer can matter: radius, reach, and
        the uncertainty of a report just short of stale. A spatial index asks this far."""
        sep = self.params.separation
        return sep.radius + self._reach + sep.peer_speed * sep.stale_after

    def filter(
        self,
        me: str,
        position: Vec,
        velocity: Vec,
        wish: Vec,
        peers: list[PeerView],
        *,
        landing: bool = False,
        fresh_peers: int | None = None,
    ) -> SafetyDecision:
        """The velocity to send for `wish` from `position` at `velocity` (all north, east, up).

        `landing` drops the fence floor (the vehicle is coming down through it on purpose).
        `fresh_peers` is how many peers are heard at all (for ``min_peers``) when `peers` holds only
        the near ones (a spatial index); None counts the fresh ones in `peers`.
        """
        p = self.params
        sep = p.separation
        north, east, up = position
        lead = sep.lead
        qn, qe, qu = north + lead * velocity[0], east + lead * velocity[1], up + lead * velocity[2]
        constraints, nearest, _ = peer_constraints(me, qn, qe, qu, peers, sep, self._reach)
        nearest_distance = math.inf
        if nearest is not None:
            nearest_distance = math.sqrt(
                (north - nearest.north) ** 2 + (east - nearest.east) ** 2 + (up - nearest.up) ** 2
            )
        name = nearest.name if nearest is not None else ""
        action, reason = "", ""
        fresh = fresh_peers
        if fresh is None:
            fresh = sum(1 for peer in peers if peer.age <= sep.stale_after) if p.min_peers else 0
        if fresh < p.min_peers:
            reason = f"no peer information: {fresh} fresh peer(s) of min_peers {p.min_peers}"
            if p.no_peers is Policy.HOVER:
                wish = (0.0, 0.0, 0.0)
                action = "hover"
            elif p.no_peers is Policy.LAND:
                action = "land"
        fence = p.fence
        if fence is not None:
            breach = fence.breach(north, east, up)
            if breach and not (landing and up < fence.floor and fence.inside_polygon(north, east)):
                return self._outside(fence, position, breach, constraints, name, nearest_distance)
            if fence.inside_polygon(qn, qe):
                north, east, up = qn, qe, qu  # the led position, as for peers
            constraints += fence.constraints(north, east, up, sep.gamma, self._reach, floor=not landing)
        solution = solve(
            wish, constraints, p.max_horizontal, p.max_vertical, vertical_weight=p.vertical_weight
        )
        by = _sources(solution)
        if not solution.feasible:
            worst = min(solution.active, key=lambda c: c.b, default=None)
            what = f"{worst.source} ({worst.what})" if worst is not None else "constraints"
            reason = reason or f"cannot keep {what}: inside the margin, backing off"
        return SafetyDecision(solution.u, by, name, nearest_distance, action, reason)

    def _outside(
        self,
        fence: Geofence,
        position: Vec,
        breach: str,
        constraints: list[Constraint],
        name: str,
        nearest_distance: float,
    ) -> SafetyDecision:
        p = self.params
        if p.outside_fence is Policy.LAND:
            return SafetyDecision((0.0, 0.0, 0.0), "fence", name, nearest_distance, "land", breach)
        if p.outside_fence is Policy.HOVER:
            return SafetyDecision((0.0, 0.0, 0.0), "fence", name, nearest_distance, "hover", breach)
        back, far = fence.way_back(*position)
        # As fast as allowed, slowing down to gamma x the distance to go (no overshoot, no stop on the line).
        speed = min(math.hypot(p.max_horizontal, p.max_vertical), p.separation.gamma * far)
        wish = clamp_speed(
            (back[0] * speed, back[1] * speed, back[2] * speed), p.max_horizontal, p.max_vertical
        )
        # Peers still count on the way back.
        solution = solve(
            wish, constraints, p.max_horizontal, p.max_vertical, vertical_weight=p.vertical_weight
        )
        return SafetyDecision(solution.u, "fence", name, nearest_distance, "", f"{breach}: flying back")


def _sources(solution: Solution) -> str:
    kinds = sorted({c.source for c in solution.active})
    return "+".join(kinds)
