"""Small, pure geodesy helpers shared by the simulator, the station and the analysis tools.

Two flavours, chosen by how much accuracy the caller needs:

* **Exact** (`distance`, `bearing`, `offset`, `local_ne`): geodesics on the WGS84 ellipsoid via
  geographiclib. Use these wherever a number is shown to a person or compared across agents (the
  station's sector sensing, log analysis): they are correct at any range, to nanometres.
* **Flat** (`FlatFrame`): a local tangent-plane approximation around a reference point, using the
  ellipsoid's meridional and prime-vertical radii of curvature at that point. It costs a few
  multiplications, which is why the simulator's inner loop uses it (200 simulated vehicles in one
  process). It differs from the exact `local_ne` (an azimuthal-equidistant frame) by an amount that
  grows with the square of the distance from the reference point (mostly east-west) and with
  tan(latitude): about 5 cm at 1 km and 5 m at 10 km at 33 deg latitude, three times that at 64 deg;
  fine for a flying field, wrong for a cross-country route.

Conventions: latitudes/longitudes in degrees (WGS84), distances in metres, bearings in degrees
clockwise from true north in [0, 360).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from geographiclib.geodesic import Geodesic

_WGS84 = Geodesic.WGS84
#: WGS84 semi-major axis (m) and flattening; used by the flat approximation.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)
_DEGREES = 180.0 / math.pi  # per radian, as `math.degrees` multiplies


def wrap_360(angle_deg: float) -> float:
    """Normalise an angle to [0, 360): headings and bearings are published in that range."""
    wrapped = math.fmod(angle_deg, 360.0)
    if wrapped < 0.0:
        wrapped += 360.0
    # fmod can return 360.0 - tiny for -tiny inputs after the addition; keep the range half-open.
    return 0.0 if wrapped >= 360.0 else wrapped


def wrap_180(angle_deg: float) -> float:
    """Normalise an angle to [-180, 180): relative bearings (left negative, right positive)."""
    return wrap_360(angle_deg + 180.0) - 180.0


def distance(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Geodesic distance in metres between two points (exact, WGS84)."""
    return float(_WGS84.Inverse(lat1, lon1, lat2, lon2, Geodesic.DISTANCE)["s12"])


def bearing(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Initial bearing (deg from north, clockwise, [0, 360)) of the geodesic from point 1 to point 2."""
    result = _WGS84.Inverse(lat1, lon1, lat2, lon2, Geodesic.AZIMUTH)
    return wrap_360(float(result["azi1"]))


def distance_bearing(lat1: float, lon1: float, lat2: float, lon2: float) -> tuple[float, float]:
    """Distance and initial bearing in one inverse solution (half the cost of calling both)."""
    result = _WGS84.Inverse(lat1, lon1, lat2, lon2, Geodesic.DISTANCE | Geodesic.AZIMUTH)
    return float(result["s12"]), wrap_360(float(result["azi1"]))


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    """The point reached by going `north_m`, `east_m` from (lat, lon) along one geodesic.

    The displacement is interpreted as a geodesic of length hypot(north, east) leaving at azimuth
    atan2(east, north), which makes it the exact inverse of `local_ne`.
    """
    dist = math.hypot(north_m, east_m)
    if dist == 0.0:
        return lat, lon
    azimuth = math.degrees(math.atan2(east_m, north_m))
    result = _WGS84.Direct(lat, lon, azimuth, dist, Geodesic.LATITUDE | Geodesic.LONGITUDE)
    return float(result["lat2"]), _wrap_lon(float(result["lon2"]))


def local_ne(lat0: float, lon0: float, lat: float, lon: float) -> tuple[float, float]:
    """(north, east) in metres of (lat, lon) seen from (lat0, lon0): the inverse of `offset`."""
    dist, azimuth = distance_bearing(lat0, lon0, lat, lon)
    rad = math.radians(azimuth)
    return dist * math.cos(rad), dist * math.sin(rad)


def body_to_ne(forward: float, right: float, heading: float) -> tuple[float, float]:
    """A horizontal vector given as (forward, right) of something facing compass ``heading`` degrees,
    as (north, east): the one body-to-NED rotation (the sim's body-frame commands, the Tello's frames).
    Its inverse is the same rotation by ``-heading``."""
    psi = math.radians(heading)
    c, s = math.cos(psi), math.sin(psi)
    return forward * c - right * s, forward * s + right * c


def metres_per_radian(lat: float) -> tuple[float, float]:
    """Metres per radian of latitude and of longitude at ``lat`` (the ellipsoid's local radii): the one
    flat-earth scale shared by the sim's frame and the station's sector prefilter."""
    phi = math.radians(lat)
    w = 1.0 - _E2 * math.sin(phi) ** 2
    return WGS84_A * (1.0 - _E2) / w**1.5, WGS84_A / math.sqrt(w) * math.cos(phi)


def _wrap_lon(lon: float) -> float:
    return wrap_180(lon) if not -180.0 <= lon < 180.0 else lon


@dataclass(frozen=True, slots=True)
class FlatFrame:
    """A local north/east plane tangent at (lat0, lon0): fast, approximate conversions.

    The radii of curvature are computed once, so each conversion is a handful of multiplications.
    Slotted: the sim's home, read by every snapshot of a flying agent (`vehicles.sim.telemetry`).
    """

    lat0: float
    lon0: float
    _m_per_rad_lat: float = field(init=False, repr=False)
    _m_per_rad_lon: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        per_rad_lat, per_rad_lon = metres_per_radian(self.lat0)
        object.__setattr__(self, "_m_per_rad_lat", per_rad_lat)
        object.__setattr__(self, "_m_per_rad_lon", per_rad_lon)

    def to_latlon(self, north_m: float, east_m: float) -> tuple[float, float]:
        """Lat/lon of a point given in metres north/east of the reference point."""
        # ``math.degrees(x)`` is ``x * (180.0 / pi)`` in C (Modules/mathmodule.c, radToDeg), float
        # for float: the sim converts 20 positions a second per flying agent without its calls.
        lat = self.lat0 + north_m / self._m_per_rad_lat * _DEGREES
        lon = self.lon0 + east_m / self._m_per_rad_lon * _DEGREES
        return lat, _wrap_lon(lon)

    def to_ne(self, lat: float, lon: float) -> tuple[float, float]:
        """Metres north/east of the reference point for a lat/lon."""
        north = math.radians(lat - self.lat0) * self._m_per_rad_lat
        east = math.radians(wrap_180(lon - self.lon0)) * self._m_per_rad_lon
        return north, east
