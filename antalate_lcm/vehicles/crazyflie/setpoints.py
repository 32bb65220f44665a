"""Velocity set-points for the Crazyflie's generic commander, built from the HLC's commands.

The HLC speaks NED (z down) or body frame (x forward, y right, z down) with a clockwise yaw rate; a
Crazyflie's set-points are in its right-handed frame (z up, yaw counter-clockwise):

* NED -> ``TYPE_VELOCITY_WORLD`` (cflib ``send_velocity_world_setpoint``): vx, vy, vz in the local
  frame and the yaw rate, deg/s counter-clockwise.
* Body -> ``TYPE_HOVER`` (``send_hover_setpoint``): forward and *left* velocity, the yaw rate, and an
  absolute height. The HLC's vertical velocity becomes a height target that the adapter integrates
  tick by tick, so "climb at 0.3 m/s" in the body frame climbs at 0.3 m/s.

A zero command is no set-point at all: the adapter hands the vehicle back to the high-level
commander, which holds position and keeps doing so if the link is lost (a streamed set-point does
not: the firmware's watchdog stops the motors 2 s after the last one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.crazyflie.frames import LocalFrame

#: Below this every component counts as zero (m/s, deg/s).
_ZERO = 1e-3
#: Lowest height target a body-frame set-point may ask (m): never into the floor.
MIN_HEIGHT = 0.1


@dataclass(frozen=True)
class SetPoint:
    """One generic-commander set-point: ``kind`` says which cflib call sends it and what the values mean.

    ``world``: (vx, vy, vz, yaw rate); ``hover``: (vx forward, vy left, yaw rate, height). Metres,
    m/s and deg/s (counter-clockwise), all in the Crazyflie's frame.
    """

    kind: Literal["world", "hover"]
    values: tuple[float, float, float, float]


def is_zero(vx: float, vy: float, vz: float, yaw_rate: float) -> bool:
    return all(abs(v) < _ZERO for v in (vx, vy, vz, yaw_rate))


def build_setpoint(
    vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame, local: LocalFrame, height: float
) -> SetPoint:
    """The set-point for an HLC command (z down, yaw rate clockwise) in `frame`.

    `height` is the body-frame height target the adapter holds (already integrated for this tick).
    """
    if not all(math.isfinite(v) for v in (vx, vy, vz, yaw_rate, height)):
        raise ValueError("velocity set-point with a non-finite component")
    if frame is Frame.NED:
        x, y = local.from_ne(vx, vy)
        return SetPoint("world", (x, y, -vz, -yaw_rate))
    return SetPoint("hover", (vx, -vy, -yaw_rate, max(height, MIN_HEIGHT)))


def next_height(height: float, vz_down: float, dt: float) -> float:
    """The body-frame height target after `dt` s of the HLC's vertical velocity (z down)."""
    if not (math.isfinite(dt) and 0.0 < dt < 1.0):
        return height  # a clock step or a stalled thread integrates nothing
    return max(height - vz_down * dt, MIN_HEIGHT)


def takeoff_duration(height_now: float, target: float, speed: float) -> float:
    """Seconds for the high-level commander's take-off from `height_now` to `target` at `speed` m/s."""
    return max(abs(target - height_now) / speed, 1.0)


def goto_duration(distance: float, speed: float) -> float:
    """Seconds for a go_to of `distance` metres at `speed` m/s (never under one second)."""
    return max(distance / speed, 1.0)
