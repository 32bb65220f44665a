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

from antalate_lcm.autopilot.base import AutopilotState, Frame
from antalate_lcm.config import Config, SafetyConfig
from antalate_lcm.geo import FlatFrame, body_to_ne
from antalate_lcm.msgs import telemetry_t
from antalate_lcm.peers import PeerTable
from antalate_lcm.safety.barrier import Vec
from antalate_lcm.safety.filter import FilterParams, Policy, SafetyDecision, SafetyFilter
from antalate_lcm.safety.separation import PeerView, SeparationParams

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
#: m (horizontal) from home at which the filtered return leg ends and the vehicle lands.
_HOME_REACHED = 0.5
#: MC states in which a peer's own HLC runs this filter (it takes half of each pair's duty).
_FILTERING_STATES = frozenset({"MISSION", "RTL"})


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
    """One agent's filter state: peers, origin, home, and the last wish (re-filtered every tick)."""

    def __init__(self, agent: str, config: Config) -> None:
        self.agent = agent
        self.config: SafetyConfig = config.safety
        self.params = filter_params(config)
        self._filter: SafetyFilter | None = None
        #: Fed only once the frame is fixed (`locate`), so peers and this vehicle share one origin.
        self.peers = PeerTable(
            agent, stale_after=self.config.stale_after, forget_after=self.config.forget_after
        )
        self._frame: FlatFrame | None = None
        self.home: tuple[float, float] | None = None  # (north, east) of the takeoff point
        if self.config.origin:
            self.locate(self.config.origin[0], self.config.origin[1])

    # ------------------------------------------------------------------ inputs
    def locate(self, lat: float, lon: float) -> None:
        """Fix the local frame at (lat, lon) (the [safety] origin, else the first valid position)."""
        if self._frame is not None:
            return
        self._frame = FlatFrame(lat, lon)
        self.peers = PeerTable(
            self.agent,
            origin=(lat, lon),
            stale_after=self.config.stale_after,
            forget_after=self.config.forget_after,
        )
        fence = self.config.fence
        params = self.params
        if fence is not None:
            params = replace(params, fence=fence.geofence((lat, lon)))
            self.params = params
        self._filter = SafetyFilter(params)

    def on_telemetry(self, agent: str, msg: telemetry_t, now: float) -> None:
        if agent != self.agent and self._frame is not None:
            self.peers.update_telemetry(agent, msg, now)

    def on_mc_state(self, agent: str, state: int, now: float) -> None:
        if agent != self.agent:
            self.peers.update_state(agent, state, now)

    def position(self, s: AutopilotState) -> Vec | None:
        """(north, east, up) of a snapshot in the local frame, None without a valid fix."""
        if not (math.isfinite(s.lat) and math.isfinite(s.lon)):
            return None
        if self._frame is None:
            self.locate(s.lat, s.lon)
        frame = self._frame
        assert frame is not None
        north, east = frame.to_ne(s.lat, s.lon)
        return north, east, s.alt

    def mark_home(self, s: AutopilotState) -> None:
        """Remember where the vehicle takes off (the filtered return leg flies back there)."""
        here = self.position(s)
        if here is not None:
            self.home = (here[0], here[1])

    # ------------------------------------------------------------------ the filter
    def views(self, now: float) -> list[PeerView]:
        out = []
        for p in self.peers.peers(now, max_age=self.config.forget_after):
            out.append(
                PeerView(
                    p.agent,
                    p.north,
                    p.east,
                    p.alt,
                    p.vn,
                    p.ve,
                    -p.vd,
                    age=max(0.0, now - p.received),
                    cooperative=p.in_air and p.mc_state in _FILTERING_STATES,
                )
            )
        return out

    def filter_velocity(
        self, s: AutopilotState, vx: float, vy: float, vz: float, frame: Frame, now: float
    ) -> Filtered | None:
        """The velocity to send for a command (as the guard passed it); None without a position fix."""
        here = self.position(s)
        if here is None or self._filter is None:
            return None
        if frame is Frame.BODY:
            vn, ve = body_to_ne(vx, vy, s.heading)
        else:
            vn, ve = vx, vy
        decision = self._filter.filter(self.agent, here, (s.vn, s.ve, -s.vd), (vn, ve, -vz), self.views(now))
        u = decision.velocity
        return Filtered(u[0], u[1], -u[2], decision)

    def return_leg(self, s: AutopilotState, now: float) -> Filtered | None:
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
        decision = self._filter.filter(self.agent, here, (s.vn, s.ve, -s.vd), wish, self.views(now))
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
