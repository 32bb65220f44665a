"""The Crazyflie's local frame and WGS84, apart from I/O so each rule has plain unit tests.

A Crazyflie's position comes from a local positioning system (Lighthouse, Loco, a Flow deck, motion
capture) in a right-handed world frame: x and y horizontal, z up, yaw in degrees counter-clockwise
from +x. antalate speaks WGS84 and north/east/down with compass headings, so the frame is pinned to
the Earth by configuration: ``origin_lat/origin_lon`` is where (0, 0) is, ``origin_heading`` the
compass heading (clockwise from north) of +x. +y is then 90 degrees *anticlockwise* from +x,
i.e. at ``origin_heading - 90``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from antalate_lcm.base.geo import local_ne, offset, wrap_360


@dataclass(frozen=True)
class LocalFrame:
    """The configured pinning of the local frame: origin (deg) and the compass heading of +x (deg)."""

    origin_lat: float
    origin_lon: float
    origin_heading: float

    def _cs(self) -> tuple[float, float]:
        h = math.radians(self.origin_heading)
        return math.cos(h), math.sin(h)

    def to_ne(self, x: float, y: float) -> tuple[float, float]:
        """A local horizontal vector as (north, east)."""
        c, s = self._cs()
        return x * c + y * s, x * s - y * c

    def from_ne(self, north: float, east: float) -> tuple[float, float]:
        """A (north, east) vector in the local frame: the inverse of `to_ne` (a reflection is its own)."""
        c, s = self._cs()
        return north * c + east * s, north * s - east * c

    def to_wgs84(self, x: float, y: float) -> tuple[float, float]:
        """(lat, lon) of a local position."""
        north, east = self.to_ne(x, y)
        return offset(self.origin_lat, self.origin_lon, north, east)

    def from_wgs84(self, lat: float, lon: float) -> tuple[float, float]:
        """The local (x, y) of a WGS84 point (for tests and for go-to targets given as coordinates)."""
        north, east = local_ne(self.origin_lat, self.origin_lon, lat, lon)
        return self.from_ne(north, east)

    def heading(self, yaw: float) -> float:
        """Compass heading [0, 360) of a vehicle whose yaw (counter-clockwise from +x) is `yaw` degrees."""
        return wrap_360(self.origin_heading - yaw)

    def velocity_ned(self, vx: float, vy: float, vz: float) -> tuple[float, float, float]:
        """A local velocity (z up) as north, east, down."""
        vn, ve = self.to_ne(vx, vy)
        return vn, ve, -vz
