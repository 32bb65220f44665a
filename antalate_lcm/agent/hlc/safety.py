"""The HLC's side of the safety filter (docs/safety.md): the peer table it is fed, the frames, the
per-vehicle defaults, the filtered return home, and what the operator is told. No I/O: the node feeds
it telemetry and snapshots and sends what it returns.

Frames: the filter works in metres north/east/up of one local origin ([safety] origin, else this
vehicle's first position: the same `PeerTable` frame behaviors get). Velocity commands arrive in
BODY or NED (z down) and leave as NED when the filter changed them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from antalate_lcm.agent.hlc.swarm_picture import SwarmPicture
from antalate_lcm.base.geo import FlatFrame, body_to_ne
from antalate_lcm.base.safety.barrier import Vec
from antalate_lcm.base.safety.filter import FilterParams, Policy, SafetyDecision, SafetyFilter
from antalate_lcm.base.safety.separation import PeerView, SeparationParams
from antalate_lcm.core.config import Config, SafetyConfig
from antalate_lcm.vehicles.base import Frame, VehicleState

#: Per vehicle (the ``[hlc] autopilot`` name): separation radius (m, horizontal), half-height (m), and
#: velocity response time constant (s). Sim: its own ``tau``. ArduCopter: WPNAV/PSC velocity loop,
#: about 0.5 s to 63 % in SITL (docs/safety.md). Crazyflie: Crazyswarm's ellipsoid (0.12 m x 0.3 m)
#: with room for its position error; Tello: its optical-flow drift of some 0.3 m.
VEHICLE_DEFAULTS: dict[str, tuple[float, float, float]] = {
    "sim": (3.0, 1.5, 0.5),
    "mavlink": (4.0, 2.0, 0.5),
    "tello": (1.0, 0.5, 0.4),
    "crazyflie": (0.4, 0.3, 0.2),
}
_UNKNOWN_VEHICLE = (4.0, 2.0, 0.5)
#: m: how far below the radius the closest approach came in the measured worst cases of docs/safety.md
#: (sim: tests/safety/test_safety_e2e.py; mavlink: three ArduCopter SITL, tests/sitl_arducopter/test_safety.py).
#: `antalate analyze --safety` compares the log's minimum separation with radius minus this.
MEASURED_MARGIN: dict[str, float] = {"sim": 0.5, "mavlink": 1.25}
#: m (horizontal) from home at which the filtered return leg ends and the vehicle lands.
_HOME_REACHED = 0.5
#: MC states in which a peer's own HLC runs this filter (it takes half of each pair's duty).
_FILTERING_STATES = frozenset({"MISSION", "RTL"})


def new_picture(config: Config) -> SwarmPicture:
    """A swarm picture for agents of this config, its grid cell the filter's horizon."""
    s = config.safety
    origin = (s.origin[0], s.origin[1]) if s.origin else None
    horizon = SafetyFilter(filter_params(config)).horizon
    return SwarmPicture(cell=horizon, stale_after=s.stale_after, forget_after=s.forget_after, origin=origin)


def filter_params(config: Config) -> FilterParams:
    """The filter's parameters: [safety] over the vehicle's defaults."""
    s, h = config.safety, config.hlc
    radius, vertical, lead = VEHICLE_DEFAULTS.get(h.autopilot, _UNKNOWN_VEHICLE)
    if h.autopilot == "sim":
        lead = float(h.autopilot_params.get("tau", lead))
    sep = SeparationParams(
        radius=s.radius or radius,
        vertical=s.vertical or vertical,
        gamma=s.gamma,
        peer_speed=s.peer_speed or h.max_horizontal_speed,
        stale_after=s.stale_after,
        lead=lead if s.lead is None else s.lead,
    )
    return FilterParams(
        sep,
        h.max_horizontal_speed,
        h.max_vertical_speed,
        fence=None,  # set once the origin is known (`SafetyLayer.locate`)
        min_peers=s.min_peers,
        no_peers=Policy(s.no_peers),
        outside_fence=Policy(s.fence.outside) if s.fence is not None else Policy.RETURN,
    )


@dataclass(frozen=True)
class Filtered:
    """A filtered set-point for the node: NED velocity (z down), and the decision behind it."""

    vn: float
    ve: float
    vd: float
    decision: SafetyDecision


class SafetyLayer:
    """One agent's filter state: its filter, its home, and the swarm picture it shares with the
    other agents of its process (`SwarmPicture`)."""

    def __init__(self, agent: str, config: Config, picture: SwarmPicture | None = None) -> None:
        self.agent = agent
        self.config: SafetyConfig = config.safety
        self.params = filter_params(config)
        self._filter: SafetyFilter | None = None
        self.picture = picture if picture is not None else new_picture(config)
        self.home: tuple[float, float] | None = None  # (north, east) of the takeoff point
        if self.picture.frame is not None:
            self._fix(self.picture.frame)

    def _fix(self, frame: FlatFrame) -> None:
        """The frame is known: place the fence in it and build the filter."""
        fence = self.config.fence
        if fence is not None:
            self.params = replace(self.params, fence=fence.geofence((frame.lat0, frame.lon0)))
        self._filter = SafetyFilter(self.params)

    # ------------------------------------------------------------------ inputs
    def position(self, s: VehicleState) -> Vec | None:
        """(north, east, up) of a snapshot in the local frame, None without a valid fix."""
        if not (math.isfinite(s.lat) and math.isfinite(s.lon) and -90.0 <= s.lat <= 90.0):
            return None
        frame = self.picture.place(s.lat, s.lon)
        if self._filter is None:
            self._fix(frame)
        north, east = frame.to_ne(s.lat, s.lon)
        return north, east, s.alt

    def mark_home(self, s: VehicleState) -> None:
        """Remember where the vehicle takes off (the filtered return leg flies back there)."""
        here = self.position(s)
        if here is not None:
            self.home = (here[0], here[1])

    def crowded(self, s: VehicleState, now: float) -> list[tuple[str, float]]:
        """The fresh peers standing or flying closer than the radius horizontally, nearest first: a
        vertical take-off from here keeps that distance (docs/safety.md, take-off)."""
        here = self.position(s)
        if here is None:
            return []
        radius = self.params.separation.radius
        out = []
        for p in self.picture.near(self.agent, here[0], here[1], radius):
            d = math.hypot(p.north - here[0], p.east - here[1])
            if d < radius and now - p.received <= self.config.stale_after:
                out.append((p.agent, d))
        return sorted(out, key=lambda x: x[1])

    # ------------------------------------------------------------------ the filter
    def views(self, here: Vec, now: float) -> list[PeerView]:
        """The peers near `here` as the filter sees them."""
        assert self._filter is not None
        out = []
        horizon = self._filter.horizon
        north, east = here[0], here[1]
        for p in self.picture.near(self.agent, north, east, horizon):
            age = max(0.0, now - p.received)
            reach = horizon + self.params.separation.peer_speed * age
            if abs(p.north - north) > reach or abs(p.east - east) > reach:
                continue  # in a neighbouring cell but out of reach: no constraint, no object
            out.append(
                PeerView(
                    p.agent,
                    p.north,
                    p.east,
                    p.alt,
                    p.vn,
                    p.ve,
                    -p.vd,
                    age,
                    p.in_air and p.mc_state in _FILTERING_STATES,
                )
            )
        return out

    def filter_velocity(
        self, s: VehicleState, vx: float, vy: float, vz: float, frame: Frame, now: float
    ) -> Filtered | None:
        """The velocity to send for a command (as the guard passed it); None without a position fix."""
        here = self.position(s)
        if here is None or self._filter is None:
            return None
        if frame is Frame.BODY:
            vn, ve = body_to_ne(vx, vy, s.heading)
        else:
            vn, ve = vx, vy
        decision = self._filter.filter(
            self.agent,
            here,
            (s.vn, s.ve, -s.vd),
            (vn, ve, -vz),
            self.views(here, now),
            fresh_peers=self.picture.fresh(self.agent),
        )
        u = decision.velocity
        return Filtered(u[0], u[1], -u[2], decision)

    def return_leg(self, s: VehicleState, now: float) -> Filtered | None:
        """The filtered RTL: towards home at ``rtl_speed`` and the current height; None once home
        (the node then lands) or without a position fix or a home."""
        here = self.position(s)
        if here is None or self.home is None or self._filter is None:
            return None
        dn, de = self.home[0] - here[0], self.home[1] - here[1]
        dist = math.hypot(dn, de)
        if dist <= _HOME_REACHED:
            return None
        speed = min(self.config.rtl_speed, self.params.separation.gamma * dist)
        wish = (dn / dist * speed, de / dist * speed, 0.0)
        decision = self._filter.filter(
            self.agent,
            here,
            (s.vn, s.ve, -s.vd),
            wish,
            self.views(here, now),
            fresh_peers=self.picture.fresh(self.agent),
        )
        u = decision.velocity
        return Filtered(u[0], u[1], -u[2], decision)


def describe(decision: SafetyDecision) -> str:
    """One line for the log, the operator's console and ``antalate analyze``."""
    parts = []
    if decision.by:
        parts.append(f"velocity modified by {decision.by}")
    if decision.reason:
        parts.append(decision.reason)
    if decision.nearest:
        parts.append(f"nearest {decision.nearest} at {decision.nearest_distance:.2f} m")
    return "safety: " + "; ".join(parts)
