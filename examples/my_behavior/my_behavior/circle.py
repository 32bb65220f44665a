"""``circle``: fly circles of a set radius while the mission runs.

A complete behavior in about fifty lines: validated params, declared topics, a periodic tick,
a subscription made on activation (and dropped by the BMA on deactivation), and a clean stop.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.core.behavior import Behavior
from antalate_lcm.msgs import telemetry_t, velocity_cmd_t


class Circle(Behavior):
    """Forward at ``speed`` while turning at ``speed / radius``: a circle of ``radius`` metres."""

    class Params(BaseModel):
        # extra="forbid": a misspelt key in [bma.behaviors.params] fails at config load.
        model_config = ConfigDict(extra="forbid", frozen=True)

        speed: float = Field(default=2.0, gt=0, le=10, description="m/s along the circle")
        radius: float = Field(default=10.0, gt=0, description="metres")
        clockwise: bool = True

    params: Params
    # The topics this behavior uses and their types; a config may remap them, checked at load.
    topics = {"VELOCITY_CMD": velocity_cmd_t, "TELEMETRY": telemetry_t}
    # Defaults used when the config gives no activate_on / tick_hz.
    activate_on = ("MISSION",)
    tick_hz = 10.0

    def on_activate(self) -> None:
        self.turned = 0.0  # degrees turned since activation
        self.altitude: float | None = None
        self.ctx.subscribe("TELEMETRY", self._on_telemetry)
        self.log.info("circling: r = %g m at %g m/s", self.params.radius, self.params.speed)

    def _on_telemetry(self, msg: telemetry_t) -> None:
        self.altitude = msg.alt

    def tick(self, dt: float) -> None:
        yaw_rate = math.degrees(self.params.speed / self.params.radius)
        if not self.params.clockwise:
            yaw_rate = -yaw_rate
        laps_before = int(self.turned // 360)
        self.turned += abs(yaw_rate) * dt
        if int(self.turned // 360) > laps_before:
            self.log.info("lap %d done (altitude %s m)", int(self.turned // 360), self.altitude)
        self._send(self.params.speed, yaw_rate)

    def on_deactivate(self) -> None:
        # Hover at once rather than waiting for the HLC's velocity timeout.
        self._send(0.0, 0.0)

    def _send(self, vx: float, yaw_rate: float) -> None:
        msg = velocity_cmd_t()
        msg.frame = velocity_cmd_t.BODY
        msg.vx, msg.yaw_rate = vx, yaw_rate
        self.ctx.publish("VELOCITY_CMD", msg)
