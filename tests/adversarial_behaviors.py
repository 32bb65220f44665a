"""Behaviors that try to crash the swarm, for the safety filter's end-to-end tests (tests/safety/test_safety_e2e.py).

`FlyAt` commands its agent straight at a fixed point (the swarm's centroid, a partner's start for a
head-on pair, a point outside the fence) at full speed, whatever is in the way, until deactivated.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict

from antalate_lcm.base.geo import local_ne
from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.msgs import telemetry_t, velocity_cmd_t


class FlyAt(Behavior):
    """Full speed at (lat, lon); it never slows down, it passes the point and comes back."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

        lat: float
        lon: float
        speed: float = 5.0

    params: Params
    topics = {"TELEMETRY": telemetry_t, "VELOCITY_CMD": velocity_cmd_t}
    activate_on = ("MISSION",)
    tick_hz = 10.0

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.here: tuple[float, float] | None = None
        ctx.subscribe("TELEMETRY", self._on_telemetry)

    def _on_telemetry(self, msg: telemetry_t) -> None:
        if math.isfinite(msg.lat) and math.isfinite(msg.lon):
            self.here = (msg.lat, msg.lon)

    def on_activate(self) -> None:
        self.tick(0.0)

    def tick(self, dt: float) -> None:
        if self.here is None:
            return
        north, east = local_ne(self.here[0], self.here[1], self.params.lat, self.params.lon)
        d = math.hypot(north, east)
        msg = velocity_cmd_t()
        msg.frame = velocity_cmd_t.NED
        s = self.params.speed / d if d > 0.05 else 0.0
        msg.vx, msg.vy, msg.vz, msg.yaw_rate = north * s, east * s, 0.0, 0.0
        self.ctx.publish("VELOCITY_CMD", msg)
