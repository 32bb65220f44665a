"""Geodesy helpers: exact round trips, known values, and the flat frame's stated accuracy."""

from __future__ import annotations

import math
import random

import pytest

from antalate_lcm.base import geo

POINTS = [
    (32.7767, 35.0231),  # Technion
    (-33.8688, 151.2093),  # Sydney
    (64.1466, -21.9426),  # Reykjavik
    (0.0, 179.9995),  # next to the antimeridian
    (0.0, 0.0),
]
OFFSETS = [(0.0, 0.0), (1000.0, 0.0), (0.0, 1000.0), (-250.0, 730.0), (12.5, -3.25), (-5000.0, -5000.0)]


@pytest.mark.parametrize("lat0, lon0", POINTS)
@pytest.mark.parametrize("north, east", OFFSETS)
def test_offset_local_ne_round_trip(lat0: float, lon0: float, north: float, east: float) -> None:
    lat, lon = geo.offset(lat0, lon0, north, east)
    assert -180.0 <= lon < 180.0
    n, e = geo.local_ne(lat0, lon0, lat, lon)
    assert n == pytest.approx(north, abs=1e-6)
    assert e == pytest.approx(east, abs=1e-6)


@pytest.mark.parametrize("lat0, lon0", POINTS)
@pytest.mark.parametrize("north, east", OFFSETS[1:])
def test_offset_distance_and_bearing_agree(lat0: float, lon0: float, north: float, east: float) -> None:
    lat, lon = geo.offset(lat0, lon0, north, east)
    dist, brg = geo.distance_bearing(lat0, lon0, lat, lon)
    assert dist == pytest.approx(math.hypot(north, east), abs=1e-6)
    assert geo.distance(lat0, lon0, lat, lon) == pytest.approx(dist)
    assert geo.bearing(lat0, lon0, lat, lon) == pytest.approx(brg)
    expected = geo.wrap_360(math.degrees(math.atan2(east, north)))
    assert abs(geo.wrap_180(brg - expected)) < 1e-7


def test_known_values() -> None:
    # One degree of latitude at the equator on WGS84.
    assert geo.distance(0.0, 0.0, 1.0, 0.0) == pytest.approx(110574.389, abs=0.01)
    assert geo.bearing(0.0, 0.0, 0.0, 1.0) == pytest.approx(90.0)
    assert geo.bearing(0.0, 0.0, -1.0, 0.0) == pytest.approx(180.0)
    assert geo.bearing(10.0, 10.0, 10.0, 9.0) == pytest.approx(270.0, abs=0.1)
    assert geo.offset(12.0, 34.0, 0.0, 0.0) == (12.0, 34.0)


@pytest.mark.parametrize(
    "angle, expected360, expected180",
    [
        (0.0, 0.0, 0.0),
        (360.0, 0.0, 0.0),
        (-90.0, 270.0, -90.0),
        (540.0, 180.0, -180.0),
        (-1e-20, 0.0, -1e-20),
        (725.5, 5.5, 5.5),
        (190.0, 190.0, -170.0),
    ],
)
def test_wrapping(angle: float, expected360: float, expected180: float) -> None:
    assert geo.wrap_360(angle) == pytest.approx(expected360)
    assert 0.0 <= geo.wrap_360(angle) < 360.0
    assert geo.wrap_180(angle) == pytest.approx(expected180)
    assert -180.0 <= geo.wrap_180(angle) < 180.0


@pytest.mark.parametrize("lat0, lon0", POINTS[:3])
@pytest.mark.parametrize("north, east", OFFSETS)
def test_flat_frame_round_trip(lat0: float, lon0: float, north: float, east: float) -> None:
    frame = geo.FlatFrame(lat0, lon0)
    n, e = frame.to_ne(*frame.to_latlon(north, east))
    assert n == pytest.approx(north, abs=1e-6)
    assert e == pytest.approx(east, abs=1e-6)


@pytest.mark.parametrize("lat0, lon0", POINTS[:3])
@pytest.mark.parametrize("distance, tolerance", [(100.0, 0.002), (1000.0, 0.1), (10_000.0, 10.0)])
def test_flat_frame_accuracy_as_documented(
    lat0: float, lon0: float, distance: float, tolerance: float
) -> None:
    # The documented figures are for mid latitudes; the error grows with tan(latitude).
    tolerance *= max(1.0, math.tan(math.radians(abs(lat0))) / math.tan(math.radians(35.0)))
    frame = geo.FlatFrame(lat0, lon0)
    for azimuth in range(0, 360, 30):
        north = distance * math.cos(math.radians(azimuth))
        east = distance * math.sin(math.radians(azimuth))
        n, e = geo.local_ne(lat0, lon0, *frame.to_latlon(north, east))
        assert math.hypot(n - north, e - east) < tolerance


def test_flat_frame_across_the_antimeridian() -> None:
    frame = geo.FlatFrame(0.0, 179.9995)
    lat, lon = frame.to_latlon(0.0, 200.0)
    assert lon < 0.0  # wrapped into [-180, 180)
    n, e = frame.to_ne(lat, lon)
    assert e == pytest.approx(200.0, abs=1e-6)


@pytest.mark.parametrize("lat0, lon0", POINTS)
def test_flat_frame_to_latlon_is_math_degrees_float_for_float(lat0: float, lon0: float) -> None:
    """`FlatFrame.to_latlon` multiplies by 180/pi where it called `math.degrees`: the same floats."""
    frame = geo.FlatFrame(lat0, lon0)
    per_lat, per_lon = geo.metres_per_radian(lat0)
    r = random.Random(lat0)
    for _ in range(20_000):
        north, east = (r.choice([-1.0, 1.0]) * 10 ** r.uniform(-9.0, 5.0) for _ in range(2))
        lon = lon0 + math.degrees(east / per_lon)
        expected = (lat0 + math.degrees(north / per_lat), lon if -180.0 <= lon < 180.0 else geo.wrap_180(lon))
        assert frame.to_latlon(north, east) == expected, (north, east)
    assert [repr(x) for x in frame.to_latlon(-0.0, -0.0)] == [repr(lat0 + -0.0), repr(lon0 + -0.0)]
