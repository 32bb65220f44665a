"""The Tello's state packets as the adapter's picture of it: link age, reading, dead-reckoned position.

The state line carries ground velocities ``vgx/vgy`` (dm/s) and ``yaw`` (deg, 0 at power-on); they are
rotated into north/east by ``home_heading`` and integrated (trapezoid rule, only while flying) from
``home_lat``/``home_lon``. Heading = ``home_heading + yaw``. Altitude is the state's ``h`` (cm,
decimetre resolution) or the ``tof`` range finder. Signs and frame of ``vgx/vgy`` are configurable
(``vgx_sign``, ``vgy_sign``, ``velocity_frame``).

The link's ``state()`` is a new object for every packet (djitellopy's receiver thread replaces its
per-drone dict), so a new object means a new packet; it is stamped with the adapter's clock when first
seen, read into the adapter's units by `telemetry.read`, and dead-reckoned. No I/O and no lock here:
the adapter calls `PacketTracker.take` holding its own.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

from antalate_lcm.base.geo import wrap_360
from antalate_lcm.vehicles.base import Clock
from antalate_lcm.vehicles.kit import LinkAge
from antalate_lcm.vehicles.tello import maths, telemetry
from antalate_lcm.vehicles.tello.params import Params

log = logging.getLogger("antalate.autopilot.tello")

GROUND_CONFIRM = 0.5  # s an in-air flag must hold before it is believed


class PacketTracker:
    """The newest state packet and what it says, in the adapter's units and frame."""

    def __init__(self, p: Params, clock: Clock, host: str) -> None:
        self._p = p
        self._clock = clock
        self._host = host
        self.home_heading = wrap_360(p.home_heading)
        self._raw: Mapping[str, Any] | None = None  # the dict object of the last packet (identity = packet)
        self.age = LinkAge(clock)  # heard_at: clock() when the newest packet was first seen
        self.reading = telemetry.StateReading()  # the newest packet in the adapter's units
        self.height_changed = -math.inf  # clock() of the last change of the height reading
        self.air = maths.Debounced(GROUND_CONFIRM)  # the in-air flag, believed once it held
        # Dead reckoning (metres north/east of home).
        self.north = self.east = 0.0
        self.units = maths.VelocityUnitCheck()

    def take(self, raw: Mapping[str, Any] | None) -> float | None:
        """Take in `raw` if it is a packet not seen before: the clock time it was first seen, else None.

        The packet as a reading (`telemetry.read`, pure), then the dead-reckoned position
        (`maths.dead_reckon`, pure). The in-air debounce is the caller's next step, after it reacted to
        a link coming back (which resets it).
        """
        if raw is None or raw is self._raw:
            return None
        now = self._clock()
        self._raw = raw
        previous, before = self.age.heard_at, self.reading
        self.age.heard(now)
        self.reading = telemetry.read(raw, self._p, self.home_heading, before)
        if self.reading.height != before.height:
            self.height_changed = now
        r = self.reading
        if self._p.velocity_unit_check and self.units.update(r.height, r.vd, r.vn, r.ve, now):
            u = self.units
            why = f"dead reckoning unreliable: {u.problem}" if u.problem else u.unchecked
            log.warning("Tello %s: %s", self._host, why)
        if previous is not None and self.in_air():
            self.north, self.east = maths.dead_reckon(
                self.north,
                self.east,
                (before.vn, before.ve),
                (self.reading.vn, self.reading.ve),
                now - previous,
            )
        return now

    def in_air(self) -> bool:
        """What the newest packet says (height above zero); `state` adds the landing in progress."""
        return self.reading.h_cm > 0

    def heading(self) -> float:
        return wrap_360(self.home_heading + self.reading.yaw)

    def distance_to(self, point: tuple[float, float]) -> float:
        """Dead-reckoned metres from here to `point` (north, east of home)."""
        return math.hypot(point[0] - self.north, point[1] - self.east)
