"""Inter-agent separation as control barrier constraints (docs/safety.md has the algorithm and its proof).

For each peer j the barrier is the distance beyond the separation radius, measured in a space whose
vertical axis is stretched by ``radius / vertical`` (so the protected volume is an ellipsoid, radius
``radius`` horizontally and ``vertical`` up and down, like Crazyswarm's downwash ellipsoids):

    h_ij = |S (p_i - p_j)| - R_ij,   S = diag(1, 1, radius / vertical)

and the constraint on agent i's commanded velocity u_i is ``dh/dt >= -gamma h`` with the pair's
duty split in half between the two agents (both run this filter: Wang, Ames, Egerstedt 2017, §IV):

    -n . S u_i <= gamma h / 2,   n = S (p_i - p_j) / |S (p_i - p_j)|

which needs only the peer's *position*, not its velocity: nothing a peer's noisy or late velocity
report can spoil. A peer that does not run the filter (`PeerView.cooperative` False: it flies an
autopilot's own RTL, or a pilot has it) gets the whole duty, and its reported velocity is used:
``-n . S u_i <= gamma h - n . S v_j``.

Distance is convex, so ``|x + dt w| >= |x| + dt n . w`` and the continuous constraint holds for the
sampled system too: with both agents holding their commands for dt (zero-order hold) and
``gamma dt <= 1``, ``h(t + dt) >= (1 - gamma dt) h(t) >= 0``. Separation never falls below R_ij while
the assumptions hold (single-integrator response, positions known); what breaks them is covered by
the radius inflation below and by the measured margin of docs/safety.md.

A vehicle does not fly its commanded velocity at once. With a first-order response of time constant
``lead`` (the sim's ``tau``; ArduCopter's and a Crazyflie's are measured in docs/safety.md) the point
``q = p + lead * v`` moves exactly at the commanded velocity (q' = v + lead v' = u), so the barrier is
applied to the led positions of both agents (the caller leads its own; peers are led here by their
reported velocity). Without the lead, the lag lets a pair overshoot the radius by up to
``lead x closing speed``.

A report of age ``a`` is inflated by ``peer_speed * a`` (the peer may have moved that far since): a
stale peer occupies a growing uncertainty ball, and for a peer older than ``stale_after`` the ball's
growth rate is part of the constraint (``-n . S u_i <= gamma h - peer_speed``): the agent backs away
from a peer it cannot see as fast as the peer could be coming.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from antalate_lcm.base.safety.barrier import Constraint


@dataclass(slots=True)
class PeerView:
    """What the filter needs to know of one other agent, in the filter's local frame.

    Positions in metres (north, east, up), velocities in m/s, `age` in seconds since the report was
    taken (receipt time plus any known latency). Not frozen: one is built per neighbour per set-point
    (a frozen dataclass's constructor costs twice as much), and nothing keeps it.
    """

    name: str
    north: float
    east: float
    up: float
    vn: float = 0.0
    ve: float = 0.0
    vu: float = 0.0
    age: float = 0.0
    #: The peer runs this filter too (takes half of each pair's duty). False: the whole duty is ours.
    cooperative: bool = True


@dataclass(frozen=True)
class SeparationParams:
    """The separation rule of one agent (the ``[safety]`` config)."""

    radius: float  # m between centres, horizontally
    vertical: float  # m between centres, vertically (the ellipsoid's half-height)
    gamma: float  # 1/s: how fast the barrier may shrink (h' >= -gamma h)
    peer_speed: float  # m/s: the fastest any peer may fly (uncertainty growth of a stale report)
    stale_after: float  # s: an older report is stale (its uncertainty ball grows in the constraint)
    #: s: the vehicles' velocity response time constant (first-order lag); positions are led by it.
    lead: float = 0.0

    def __post_init__(self) -> None:
        for name in ("radius", "vertical", "gamma", "peer_speed", "stale_after"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"SeparationParams.{name} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(self.lead) and self.lead >= 0.0):
            raise ValueError(f"SeparationParams.lead must be a finite number >= 0, got {self.lead!r}")

    @property
    def stretch(self) -> float:
        """The vertical scale of the barrier space (1 for a sphere)."""
        return self.radius / self.vertical


def separation(dn: float, de: float, du: float, stretch: float) -> float:
    """The barrier-space distance of an offset: ``|S d|``; below the radius is a loss of separation."""
    return math.sqrt(dn * dn + de * de + (du * stretch) ** 2)


def peer_constraints(
    me: str,
    north: float,
    east: float,
    up: float,
    peers: list[PeerView],
    params: SeparationParams,
    reach: float,
) -> tuple[list[Constraint], PeerView | None, float]:
    """Agent `me`'s constraints from the peers within `reach` of the radius, the nearest peer and its distance.

    `reach` (m beyond the inflated radius) is how far a constraint can bind at all: beyond
    ``2 * max_speed / gamma`` the barrier allows more than full speed, so far peers are skipped before
    any square root (this scan is the filter's cost per agent: benchmarks/safety_filter.py).
    The distance returned is in barrier space (the ellipsoid's), measured to the peer's reported position.
    """
    s = params.stretch
    gamma = params.gamma
    radius = params.radius
    out: list[Constraint] = []
    nearest: PeerView | None = None
    nearest_d = math.inf
    box = radius + reach
    lead = params.lead
    for peer in peers:
        dn = north - peer.north - lead * peer.vn
        de = east - peer.east - lead * peer.ve
        du = (up - peer.up - lead * peer.vu) * s
        inflate = params.peer_speed * max(0.0, peer.age)
        lim = box + inflate
        if dn > lim or dn < -lim or de > lim or de < -lim or du > lim or du < -lim:
            continue
        d = math.sqrt(dn * dn + de * de + du * du)
        if d < nearest_d:
            nearest, nearest_d = peer, d
        r = radius + inflate
        h = d - r
        if h > reach:
            continue
        if d < 1e-9:
            # Exactly on top of each other: no direction to part along; the names decide (north for
            # the smaller), so two coincident agents part instead of both choosing the same way.
            dn, de, du, d = (1.0 if me < peer.name else -1.0), 0.0, 0.0, 1.0
        nn, ne, nu = dn / d, de / d, du / d
        a = (-nn, -ne, -nu * s)
        if peer.age > params.stale_after:
            b = gamma * h - params.peer_speed
        elif peer.cooperative:
            b = gamma * h / 2.0
        else:
            b = gamma * h - (nn * peer.vn + ne * peer.ve + nu * s * peer.vu)
        out.append(Constraint(a, b, "separation", peer.name))
    return out, nearest, nearest_d
