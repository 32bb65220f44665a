"""The canonical swarm rules, pure: a velocity (north, east, m/s) from where this agent and its peers are.

Every rule works on positions relative to this agent (metres north/east, from
``PeerTable.relative``) and peers' velocities, so it does not depend on any frame's origin. Each
returns a horizontal velocity set-point; altitude is the takeoff altitude (the HLC holds it).

Separation is shared (:func:`separate`): every rule keeps ``separation`` metres from every peer by
limiting how fast it may close on each one to a speed proportional to the gap left. The gain is
what the vehicle's velocity lag allows: the simulator follows a set-point with a time constant
tau = 0.5 s (docs/behaviors.md, "The simulator"), so a vehicle told to stop travels about v * tau further.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

Vec = tuple[float, float]
#: Passes of separate() over the neighbours.
_PASSES = 10
#: m inside the dispersion area's edge where outward motion stops.
_EDGE = 2.0


@dataclass(frozen=True)
class Neighbour:
    """A peer as a rule sees it: where it is relative to this agent (m) and how it moves (m/s)."""

    north: float
    east: float
    vn: float = 0.0
    ve: float = 0.0

    @property
    def distance(self) -> float:
        return math.hypot(self.north, self.east)


def clamp(v: Vec, limit: float) -> Vec:
    """``v`` scaled down to at most ``limit`` m/s."""
    speed = math.hypot(*v)
    if speed <= limit or speed == 0.0:
        return v
    return v[0] * limit / speed, v[1] * limit / speed


def separate(v: Vec, neighbours: Sequence[Neighbour], separation: float, margin: float, gain: float) -> Vec:
    """``v`` with its approach on every neighbour limited to ``gain`` x (the gap beyond ``separation +
    margin``) m/s: full speed far away, slower and slower as the gap closes, and away from a
    neighbour inside ``separation + margin`` (the limit is then negative).

    Why a limit that shrinks with the gap rather than a fixed band: the vehicle follows a set-point
    with a lag (tau = 0.5 s in the simulator), and both agents of a pair slow down, so a pair closes
    at most at 2 x gain x gap; with 2 x gain <= 1 / (4 tau) the gap shrinks without overshoot
    (a critically damped second-order approach), whatever the speed the rule asked for.

    Each limit is applied in turn, a few passes over all (easing off one neighbour may close on
    another); an agent squeezed between neighbours on opposite sides cannot back away from both,
    and gets the compromise of the last pass.
    """
    vn, ve = v
    for _ in range(_PASSES):
        for nb in neighbours:
            d = nb.distance
            if d < 1e-6:  # on top of each other: any way out is as good as another, pick a fixed one
                un, ue = 1.0, 0.0
            else:
                un, ue = nb.north / d, nb.east / d  # unit vector towards the neighbour
            allowed = gain * (d - separation - margin)
            closing = vn * un + ve * ue
            if closing > allowed:
                vn -= (closing - allowed) * un
                ve -= (closing - allowed) * ue
    return vn, ve


def radius(points: Sequence[Vec]) -> float:
    """The largest distance from the points' centroid (0 for fewer than two)."""
    if len(points) < 2:
        return 0.0
    cn = sum(p[0] for p in points) / len(points)
    ce = sum(p[1] for p in points) / len(points)
    return max(math.hypot(p[0] - cn, p[1] - ce) for p in points)


class RuleParams(BaseModel):
    """What every rule takes: its speed and the separation it keeps (:func:`separate`). A rule
    redeclares a field whose default differs. Validated, since the plugins' ``Params`` are these (one
    list of names, defaults and bounds for the rule and its config)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    #: m/s, the fastest the rule asks for (flocking: the speed it cruises at).
    speed: float = Field(default=1.5, gt=0, allow_inf_nan=False)
    #: m kept from every peer, the margin aimed for beyond it, and the closing speed per metre of gap (1/s):
    #: 0.25 per agent keeps a closing pair critically damped under the simulator's 0.5 s lag.
    separation: float = Field(default=3.0, ge=0, allow_inf_nan=False)
    margin: float = Field(default=0.3, ge=0, allow_inf_nan=False)
    separation_gain: float = Field(default=0.25, gt=0, allow_inf_nan=False)


# ---------------------------------------------------------------------------------------------- gathering
class GatheringParams(RuleParams):
    #: 1/s: velocity per metre to the centroid (slows down on arrival).
    gain: float = Field(default=0.4, gt=0, allow_inf_nan=False)
    #: (faster than critically damped: 8 agents gathered from a 6 m grid kept 3.29 m, docs/behaviors.md)
    separation_gain: float = Field(default=0.5, gt=0, allow_inf_nan=False)
    #: Stop closing in once the swarm (this agent and its peers) is within this radius, m; 0 = never.
    stop_radius: float = Field(default=4.5, ge=0, allow_inf_nan=False)
    #: m/s of random motion added to the approach (the caller draws it, ``jitter`` argument): agents
    #: that close in on a square grid otherwise jam in that shape, every one blocked by two neighbours
    #: (8 agents from an 8 m grid stopped at a radius of 5.3 m with 3.3 m spacing); a little noise
    #: lets them slide into the gaps, as in stochastic aggregation models.
    jitter: float = Field(default=0.5, ge=0, allow_inf_nan=False)
    #: m beyond ``separation + margin`` where a soft push away from a neighbour starts: a pushed
    #: neighbour moves aside, so the swarm settles into a round cluster rather than jamming.
    cushion: float = Field(default=1.0, ge=0, allow_inf_nan=False)


def gathering(neighbours: Sequence[Neighbour], p: GatheringParams, jitter: Vec = (0.0, 0.0)) -> Vec:
    """Aggregation: towards the centroid of the peers, keeping ``separation``; still once gathered.

    ``jitter`` is a random direction (a unit vector, or zero) the caller draws each tick; it is
    scaled by ``p.jitter`` and added to the approach while not gathered."""
    if not neighbours:
        return 0.0, 0.0
    cn = sum(nb.north for nb in neighbours) / len(neighbours)
    ce = sum(nb.east for nb in neighbours) / len(neighbours)
    gathered = (
        p.stop_radius > 0
        and radius([(0.0, 0.0), *((nb.north, nb.east) for nb in neighbours)]) < p.stop_radius
    )
    if gathered:
        want = (0.0, 0.0)
    else:
        vn, ve = clamp((p.gain * cn, p.gain * ce), p.speed)
        vn, ve = vn + p.jitter * jitter[0], ve + p.jitter * jitter[1]
        reach = p.separation + p.margin + p.cushion
        for nb in neighbours:  # soft repulsion: a neighbour pushed gives way to the one behind
            d = nb.distance
            if 1e-6 < d < reach:
                push = p.gain * 2.0 * (reach - d)
                vn, ve = vn - push * nb.north / d, ve - push * nb.east / d
        want = clamp((vn, ve), p.speed)
    return clamp(separate(want, neighbours, p.separation, p.margin, p.separation_gain), p.speed)


# ---------------------------------------------------------------------------------------------- flocking
class FlockingParams(RuleParams):
    #: m: peers within this distance are neighbours (Reynolds' perception radius); 0 = every peer.
    neighbourhood: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    #: Weights of alignment (match the neighbours' mean velocity) and cohesion (towards their centroid).
    alignment: float = Field(default=3.0, ge=0, allow_inf_nan=False)
    cohesion: float = Field(default=0.05, ge=0, allow_inf_nan=False)
    margin: float = Field(default=0.5, ge=0, allow_inf_nan=False)
    #: Initial heading of the cruise (deg from north) when no neighbour moves yet.
    heading: float = Field(default=0.0, allow_inf_nan=False)


def flocking(velocity: Vec, neighbours: Sequence[Neighbour], p: FlockingParams) -> Vec:
    """Reynolds' boids (separation, alignment, cohesion) at a preferred speed, Vicsek-style: each
    agent steers towards its neighbours' mean heading and flies at ``speed``.

    ``velocity`` is this agent's own (m/s, north/east); with nobody moving yet, the flock sets off
    along ``heading``.
    """
    near = [nb for nb in neighbours if p.neighbourhood <= 0 or nb.distance <= p.neighbourhood]
    hn, he = velocity
    if near:
        mn = sum(nb.vn for nb in near) / len(near)
        me = sum(nb.ve for nb in near) / len(near)
        hn, he = hn + p.alignment * mn, he + p.alignment * me
        cn = sum(nb.north for nb in near) / len(near)
        ce = sum(nb.east for nb in near) / len(near)
        hn, he = hn + p.cohesion * cn, he + p.cohesion * ce
    if math.hypot(hn, he) < 0.1 * p.speed:  # nobody moves (yet): the common initial heading
        rad = math.radians(p.heading)
        hn, he = math.cos(rad), math.sin(rad)
    norm = math.hypot(hn, he)
    want = (p.speed * hn / norm, p.speed * he / norm)
    return clamp(separate(want, neighbours, p.separation, p.margin, p.separation_gain), 1.5 * p.speed)


# ---------------------------------------------------------------------------------------------- dispersion
class DispersionParams(RuleParams):
    #: m: the spacing the swarm spreads to (each agent moves away from peers nearer than this).
    spacing: float = Field(default=10.0, gt=0, allow_inf_nan=False)
    #: m: never farther than this from the home the agent took off from (the area to cover); 0 = no bound.
    area_radius: float = Field(default=30.0, ge=0, allow_inf_nan=False)


def dispersion(home: Vec, neighbours: Sequence[Neighbour], p: DispersionParams) -> Vec:
    """Area coverage by dispersion: away from every peer nearer than ``spacing`` (more the nearer),
    still once every peer is at least ``spacing`` away; pulled back inside ``area_radius`` of
    ``home`` (the home relative to this agent, m)."""
    vn = ve = 0.0
    for nb in neighbours:
        d = nb.distance
        if d >= p.spacing:
            continue
        un, ue = (1.0, 0.0) if d < 1e-6 else (nb.north / d, nb.east / d)
        weight = (p.spacing - d) / p.spacing
        vn -= weight * un
        ve -= weight * ue
    want = clamp((vn * p.speed, ve * p.speed), p.speed)
    out = math.hypot(*home)  # metres from home; home[i] / out points back to it
    if p.area_radius > 0 and out > p.area_radius:  # outside the area: straight back in
        want = clamp(home, p.speed)
    elif p.area_radius > 0 and out > p.area_radius - _EDGE:  # at the edge: no further outwards
        un, ue = -home[0] / out, -home[1] / out
        outward = want[0] * un + want[1] * ue
        if outward > 0:
            want = (want[0] - outward * un, want[1] - outward * ue)
    return clamp(separate(want, neighbours, p.separation, p.margin, p.separation_gain), p.speed)
