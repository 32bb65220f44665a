"""The operator's direction as the vehicle's velocity: steering from the console's direction keys.

The operator console (and the station) send ``direction_cmd_t``: an azimuth (deg from north), a
speed (m/s) and ``active``. This behavior turns the latest one into a NED velocity set-point,
``speed * (cos azimuth, sin azimuth)``, published at ``tick_hz`` while active (MISSION by default);
zero when the direction is inactive, when none has arrived for ``timeout`` s (the console repeats
its direction every second while one is set, so silence means the operator is gone), and once on
deactivation. It is the simplest mission a single vehicle can fly by hand; ``dovrat_swarm`` blends the
same input into a swarm rule instead.

Directions come from ``DIRECTION_CMD`` (this agent's) and ``SWARM_DIRECTION_CMD`` (everyone's),
``target`` empty or this agent; the node has authenticated them already when a swarm key is set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.msgs import direction_cmd_t, velocity_cmd_t
from behaviors.velocity import velocity_cmd


@dataclass(frozen=True)
class Direction:
    """The fields of ``direction_cmd_t`` that matter here, and when it arrived (executor clock)."""

    active: bool
    azimuth: float  # deg from north
    speed: float  # m/s
    received: float


def follow_velocity(
    direction: Direction | None, now: float, *, timeout: float, max_speed: float
) -> tuple[float, float]:
    """North/east m/s for `direction` at `now`: zero when there is none, it is inactive, stale or bad."""
    if direction is None or not direction.active or now - direction.received > timeout:
        return 0.0, 0.0
    if not (math.isfinite(direction.azimuth) and math.isfinite(direction.speed)) or direction.speed <= 0.0:
        return 0.0, 0.0
    speed = min(direction.speed, max_speed) if max_speed > 0 else direction.speed
    azimuth = math.radians(direction.azimuth)
    return speed * math.cos(azimuth), speed * math.sin(azimuth)


class DirectionFollow(Behavior):
    """Fly where the operator points, at the speed they set (NED velocity); hover otherwise."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

        #: Seconds without a direction command after which the vehicle hovers (the console repeats
        #: an active direction every second).
        timeout: float = Field(default=3.0, gt=0, allow_inf_nan=False)
        #: Cap on the commanded speed in m/s; 0 = none (the HLC's max_horizontal_speed clamps anyway).
        max_speed: float = Field(default=0.0, ge=0, allow_inf_nan=False)

    params: Params
    topics = {
        "DIRECTION_CMD": direction_cmd_t,
        "SWARM_DIRECTION_CMD": direction_cmd_t,
        "VELOCITY_CMD": velocity_cmd_t,
    }
    activate_on = ("MISSION",)
    tick_hz = 10.0

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.direction: Direction | None = None
        # For the life of the BMA: a direction set before MISSION is flown on entering it.
        ctx.subscribe("DIRECTION_CMD", self._on_direction)
        ctx.subscribe("SWARM_DIRECTION_CMD", self._on_direction)

    def _on_direction(self, msg: direction_cmd_t) -> None:
        if msg.target not in ("", self.ctx.agent):
            return
        self.direction = Direction(bool(msg.active), float(msg.azimuth), float(msg.speed), self.ctx.now)
        self.log.info(
            "operator direction: %s", f"{msg.azimuth:.0f} deg at {msg.speed:g} m/s" if msg.active else "none"
        )

    def on_activate(self) -> None:
        self.tick(0.0)

    def tick(self, dt: float) -> None:
        p = self.params
        vn, ve = follow_velocity(self.direction, self.ctx.now, timeout=p.timeout, max_speed=p.max_speed)
        self._publish(vn, ve)

    def on_deactivate(self) -> None:
        self._publish(0.0, 0.0)

    def _publish(self, vn: float, ve: float) -> None:
        self.ctx.publish("VELOCITY_CMD", velocity_cmd(vn, ve))
