"""Front-sector peer detection on the WGS84 ellipsoid (pure: no I/O, no clock).

A peer is *inside the front sector* of a reporter when the geodesic from the reporter to the peer
is at most ``range_m`` long and leaves at an azimuth within ``fov_deg / 2`` of the reporter's
heading (both edges included). Distances and azimuths come from geographiclib's inverse geodesic,
as in the AntAlate paper's station, so the answer is exact at any latitude and any range.

An inverse geodesic costs ~50 µs in pure Python, which matters at thousands of reports a second
with dozens of neighbours each. `detect` therefore rejects the plainly-outside peers first with a
local tangent-plane estimate whose error bound is known (`_FlatPrefilter`), and solves the
geodesic only for the rest. The prefilter only ever *keeps* borderline peers, so the result is
identical to solving every peer exactly (a test checks that on random swarms).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from geographiclib.geodesic import Geodesic

_WGS84 = Geodesic.WGS84
_MASK = Geodesic.DISTANCE | Geodesic.AZIMUTH
_A = 6378137.0
_E2 = (1.0 / 298.257223563) * (2.0 - 1.0 / 298.257223563)
#: Below this distance the azimuth between two points is numerically meaningless: a peer this close
#: counts as dead ahead (bearing 0) and is always inside the sector when within range.
COINCIDENT_M = 1e-3


@dataclass(frozen=True, slots=True)
class Detection:
    """The answer for one reporter: the fields of ``peer_detection_t``."""

    detected: bool
    count: int
    nearest_range: float
    nearest_bearing: float


NO_DETECTION = Detection(False, 0, 0.0, 0.0)


def relative_bearing(azimuth_deg: float, heading_deg: float) -> float:
    """Bearing of an azimuth relative to a heading, clockwise positive, in (-180, 180].

    The half-open side is the one ``peer_detection_t`` documents: dead astern is +180, never -180.
    """
    rel = math.fmod(azimuth_deg - heading_deg, 360.0)
    if rel <= -180.0:
        rel += 360.0
    elif rel > 180.0:
        rel -= 360.0
    return rel


def in_sector(
    lat: float, lon: float, heading: float, peer_lat: float, peer_lon: float, range_m: float, fov_deg: float
) -> tuple[bool, float, float]:
    """Exact test of one peer: ``(inside, distance_m, relative_bearing_deg)``.

    Always solves the geodesic; this is the reference `detect` must agree with.
    """
    result = _WGS84.Inverse(lat, lon, peer_lat, peer_lon, _MASK)
    dist = float(result["s12"])
    if dist < COINCIDENT_M:
        return dist <= range_m, dist, 0.0
    rel = relative_bearing(float(result["azi1"]), heading)
    return dist <= range_m and abs(rel) <= fov_deg / 2.0, dist, rel


class _FlatPrefilter:
    """Cheap, conservative rejection of peers that are clearly out of range or out of the field of view.

    Uses the meridional and prime-vertical radii of curvature at the reporter. For the short ranges
    it is enabled for (≤ `MAX_RANGE_M`, away from the poles) the planar distance and azimuth differ
    from the geodesic ones by far less than the margins below, so a peer it rejects is outside the
    sector for certain; anything near an edge goes on to the exact test.
    """

    # At 5 km and 80° of latitude the planar scale is off by < 0.5 % and the azimuth by < 0.3°,
    # well inside the margins; beyond that the exact test runs on every candidate.
    MAX_RANGE_M = 5_000.0
    MAX_ABS_LAT = 80.0
    _RANGE_MARGIN = 1.01  # relative
    _RANGE_SLACK_M = 1.0
    _FOV_MARGIN_DEG = 1.0
    #: Closer than this the planar azimuth is not trusted enough to reject on the field of view.
    _NEAR_M = 10.0

    __slots__ = ("_lat", "_lon", "_k_north", "_k_east", "_max_d2", "_cos_half", "_omni")

    def __init__(self, lat: float, lon: float, range_m: float, fov_deg: float) -> None:
        phi = math.radians(lat)
        w = 1.0 - _E2 * math.sin(phi) ** 2
        self._lat = lat
        self._lon = lon
        self._k_north = math.radians(1.0) * _A * (1.0 - _E2) / w**1.5  # metres per degree of latitude
        self._k_east = math.radians(1.0) * _A / math.sqrt(w) * math.cos(phi)  # per degree of longitude
        max_d = range_m * self._RANGE_MARGIN + self._RANGE_SLACK_M
        self._max_d2 = max_d * max_d
        half = fov_deg / 2.0 + self._FOV_MARGIN_DEG
        self._omni = half >= 180.0
        self._cos_half = math.cos(math.radians(half))

    @classmethod
    def usable(cls, lat: float, range_m: float) -> bool:
        return range_m <= cls.MAX_RANGE_M and abs(lat) <= cls.MAX_ABS_LAT

    def may_be_inside(self, peer_lat: float, peer_lon: float, hn: float, he: float) -> bool:
        """False only when the peer is certainly outside; (hn, he) is the heading's unit vector."""
        dlon = peer_lon - self._lon
        if dlon > 180.0:
            dlon -= 360.0
        elif dlon < -180.0:
            dlon += 360.0
        north = (peer_lat - self._lat) * self._k_north
        east = dlon * self._k_east
        d2 = north * north + east * east
        if d2 > self._max_d2:
            return False
        if self._omni or d2 < self._NEAR_M * self._NEAR_M:
            return True
        # cos(angle off the heading) compared without a square root or an atan2.
        return north * hn + east * he >= self._cos_half * math.sqrt(d2)


def detect(
    lat: float,
    lon: float,
    heading: float,
    peers: Iterable[tuple[float, float]],
    range_m: float,
    fov_deg: float,
) -> Detection:
    """Count the peers inside the front sector and give the nearest one's range and bearing.

    ``peers`` are (lat, lon) pairs, not including the reporter itself. Ties for the nearest are
    broken by the order of ``peers``.
    """
    prefilter = _FlatPrefilter(lat, lon, range_m, fov_deg) if _FlatPrefilter.usable(lat, range_m) else None
    hn = math.cos(math.radians(heading))
    he = math.sin(math.radians(heading))
    count = 0
    best_d = math.inf
    best_rel = 0.0
    for peer_lat, peer_lon in peers:
        if prefilter is not None and not prefilter.may_be_inside(peer_lat, peer_lon, hn, he):
            continue
        inside, dist, rel = in_sector(lat, lon, heading, peer_lat, peer_lon, range_m, fov_deg)
        if inside:
            count += 1
            if dist < best_d:
                best_d, best_rel = dist, rel
    if count == 0:
        return NO_DETECTION
    return Detection(True, count, best_d, best_rel)
