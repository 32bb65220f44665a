"""Front-sector peer detection on the WGS84 ellipsoid (pure: no I/O, no clock).

A peer is *inside the front sector* of a reporter when the geodesic from the reporter to the peer
is at most ``range_m`` long and leaves at an azimuth within ``fov_deg / 2`` of the reporter's
heading (both edges included). Distances and azimuths come from geographiclib's inverse geodesic,
as in the AntAlate paper's station, so the answer is exact at any latitude and any range.

An inverse geodesic costs ~50 µs in pure Python, which matters at thousands of reports a second
with dozens of neighbours each. `detect` therefore sorts peers with a local tangent-plane
estimate whose error bound is known (`_Flat`): certainly outside, certainly inside, or near an
edge; only the last kind, and the few certainly-inside peers that could be the nearest, are
solved on the ellipsoid. Every borderline case is solved exactly, so the answer is the one
solving every peer would give (a test checks that on random swarms). `search_box` gives the
spatial index the region to scan.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from geographiclib.geodesic import Geodesic

from antalate_lcm.base.geo import WGS84_A, metres_per_radian

_WGS84 = Geodesic.WGS84
_MASK = Geodesic.DISTANCE | Geodesic.AZIMUTH
#: Metres per degree of latitude at the equator, the smallest anywhere on WGS84.
_MIN_M_PER_DEG_LAT = 110_574.0
#: Relative widening of the search box beyond the planar sector: covers the planar approximation's
#: error (≤ 0.5 %) and the difference between a geodesic and a straight line on the chart.
_BOX_SLACK = 0.02
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


class _Flat:
    """Planar estimates around the reporter, with error bounds, to avoid most geodesic solutions.

    Uses the meridional and prime-vertical radii of curvature at the reporter. Within the limits it
    is enabled for (range ≤ `MAX_RANGE_M`, latitude within ±`MAX_ABS_LAT`) the planar distance is
    within 0.5 % of the geodesic one and the planar azimuth within 0.3° of the geodesic initial
    azimuth (the scale change across the range and half the meridian convergence; a test checks
    the bounds on random samples). With margins twice as wide, each peer falls in one of three
    classes: certainly outside, certainly inside (counted without solving), or near an edge (solved
    exactly). Closer than `NEAR_M` the azimuth is always solved exactly.
    """

    MAX_RANGE_M = 5_000.0
    MAX_ABS_LAT = 80.0
    REL_MARGIN = 0.01
    SLACK_M = 1.0
    FOV_MARGIN_DEG = 1.0
    NEAR_M = 10.0

    __slots__ = (
        "lat",
        "lon",
        "k_north",
        "k_east",
        "hn",
        "he",
        "out_d2",
        "in_d2",
        "cos_out",
        "cos_in",
        "omni",
    )

    def __init__(self, lat: float, lon: float, heading: float, range_m: float, fov_deg: float) -> None:
        self.lat = lat
        self.lon = lon
        per_rad_lat, per_rad_lon = metres_per_radian(lat)
        self.k_north = math.radians(1.0) * per_rad_lat  # metres per degree of latitude
        self.k_east = math.radians(1.0) * per_rad_lon  # per degree of longitude
        self.hn = math.cos(math.radians(heading))
        self.he = math.sin(math.radians(heading))
        out_d = range_m * (1.0 + self.REL_MARGIN) + self.SLACK_M
        in_d = range_m * (1.0 - self.REL_MARGIN) - self.SLACK_M
        self.out_d2 = out_d * out_d
        self.in_d2 = in_d * in_d if in_d > 0.0 else -1.0
        half = fov_deg / 2.0
        self.omni = half - self.FOV_MARGIN_DEG >= 180.0
        self.cos_out = (
            -2.0
            if half + self.FOV_MARGIN_DEG >= 180.0
            else math.cos(math.radians(half + self.FOV_MARGIN_DEG))
        )
        self.cos_in = (
            math.cos(math.radians(half - self.FOV_MARGIN_DEG)) if half > self.FOV_MARGIN_DEG else 2.0
        )

    @classmethod
    def usable(cls, lat: float, range_m: float) -> bool:
        return range_m <= cls.MAX_RANGE_M and abs(lat) <= cls.MAX_ABS_LAT

    def classify(self, peer_lat: float, peer_lon: float) -> float:
        """Planar distance when the peer is certainly inside, -1 when certainly outside, -2 to solve."""
        dlon = peer_lon - self.lon
        if dlon > 180.0:
            dlon -= 360.0
        elif dlon < -180.0:
            dlon += 360.0
        north = (peer_lat - self.lat) * self.k_north
        east = dlon * self.k_east
        d2 = north * north + east * east
        if d2 > self.out_d2:
            return -1.0
        if d2 < self.NEAR_M * self.NEAR_M:
            return -2.0
        d = math.sqrt(d2)
        # cos(angle off the heading), compared without an atan2.
        cos_off = (north * self.hn + east * self.he) / d
        if cos_off < self.cos_out:
            return -1.0
        if d2 <= self.in_d2 and (self.omni or cos_off >= self.cos_in):
            return d
        return -2.0


def detect(
    lat: float,
    lon: float,
    heading: float,
    peers: Iterable[tuple[float, float]],
    range_m: float,
    fov_deg: float,
) -> Detection:
    """Count the peers inside the front sector and give the nearest one's range and bearing.

    ``peers`` are (lat, lon) pairs, not including the reporter itself. The answer equals calling
    `in_sector` on every peer (ties for the nearest aside); the reported range and bearing always
    come from the geodesic solution.
    """
    # Long ranges and polar regions, where the planar bounds do not hold: every peer is solved.
    flat = _Flat(lat, lon, heading, range_m, fov_deg) if _Flat.usable(lat, range_m) else None
    count = 0
    best_d = math.inf
    best_rel = 0.0
    sure: list[tuple[float, float, float]] = []  # planar distance, lat, lon of certainly-inside peers
    for peer_lat, peer_lon in peers:
        cls = flat.classify(peer_lat, peer_lon) if flat is not None else -2.0
        if cls == -1.0:
            continue
        if cls >= 0.0:
            sure.append((cls, peer_lat, peer_lon))
            continue
        inside, dist, rel = in_sector(lat, lon, heading, peer_lat, peer_lon, range_m, fov_deg)
        if inside:
            count += 1
            if dist < best_d:
                best_d, best_rel = dist, rel
    if sure:
        count += len(sure)
        # Only the peers that could be the nearest, given the planar error, need their exact range.
        limit = min(p[0] for p in sure) * (1.0 + _Flat.REL_MARGIN) + _Flat.SLACK_M
        for planar, peer_lat, peer_lon in sure:
            if planar <= limit:
                _, dist, rel = in_sector(lat, lon, heading, peer_lat, peer_lon, range_m, fov_deg)
                if dist < best_d:
                    best_d, best_rel = dist, rel
    if count == 0:
        return NO_DETECTION
    return Detection(True, count, best_d, best_rel)


def search_box(
    lat: float, lon: float, heading: float, range_m: float, fov_deg: float
) -> tuple[float, float, float, float]:
    """(south, north, west, east) in degrees enclosing the sector, generously: what the index scans.

    A narrow sector needs a box a quarter the size of the circle's, so the index hands over a
    quarter of the candidates. ``west`` may exceed ``east`` (the box crosses the antimeridian), and
    the box becomes every longitude when it reaches a pole.
    """
    reach = range_m * (1.0 + _Flat.REL_MARGIN) + _Flat.SLACK_M
    half = fov_deg / 2.0 + _Flat.FOV_MARGIN_DEG
    # Extremes of the sector in a local north/east plane: the apex, the two arc ends, and every
    # compass point the arc sweeps through.
    norths, easts = [0.0], [0.0]
    if not _Flat.usable(lat, range_m):
        # Beyond the planar bounds: the box of the whole circle, from bounds that hold anywhere
        # (a degree of latitude is ≥ 110,574 m; a parallel's radius is ≥ a·cos(latitude)).
        reach = range_m
        half = 180.0
    if half >= 180.0:
        norths += [reach, -reach]
        easts += [reach, -reach]
    else:
        for az in (heading - half, heading + half):
            norths.append(reach * math.cos(math.radians(az)))
            easts.append(reach * math.sin(math.radians(az)))
        for compass in (0.0, 90.0, 180.0, 270.0):
            if abs(relative_bearing(compass, heading)) <= half:
                norths.append(reach * math.cos(math.radians(compass)))
                easts.append(reach * math.sin(math.radians(compass)))
    # Conservative metres-per-degree: the equator's for latitude (the smallest), and for longitude
    # the parallel of the most poleward latitude the box reaches, with the sphere of radius a
    # (smaller than the ellipsoid's parallels there).
    slack = 1.0 + _BOX_SLACK
    south = lat + min(norths) * slack / _MIN_M_PER_DEG_LAT
    north = lat + max(norths) * slack / _MIN_M_PER_DEG_LAT
    south, north = max(-90.0, south), min(90.0, north)
    cos_pole = math.cos(math.radians(max(abs(south), abs(north))))
    if cos_pole < 1e-9:
        return south, north, -180.0, 180.0
    m_per_deg_lon = math.radians(1.0) * WGS84_A * cos_pole
    west = lon + min(easts) * slack / m_per_deg_lon
    east = lon + max(easts) * slack / m_per_deg_lon
    if east - west >= 360.0:
        return south, north, -180.0, 180.0
    return south, north, _wrap_lon(west), _wrap_lon(east)


def _wrap_lon(lon: float) -> float:
    wrapped = math.fmod(lon + 180.0, 360.0)
    if wrapped < 0.0:
        wrapped += 360.0
    return wrapped - 180.0
