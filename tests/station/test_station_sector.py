"""Station geometry without sockets: the sector test, its shortcuts and the spatial index.

The reference for "right" is independent of the code under test: a local tangent-plane model
written here from the WGS84 radii of curvature (accurate to millimetres over the ~100 m used), and
brute force (the exact test applied to every peer) for the shortcuts and the index.
"""

from __future__ import annotations

import math
import random

import pytest
from geographiclib.geodesic import Geodesic

from antalate_lcm.station import sector
from antalate_lcm.station._spatial import GridIndex
from antalate_lcm.station.sector import Detection, detect, in_sector, relative_bearing, search_box

A = 6378137.0
F = 1 / 298.257223563
E2 = F * (2 - F)


def radii(lat: float) -> tuple[float, float]:
    """(metres per radian north, metres per radian east) at a latitude: M and N·cos(lat)."""
    s = math.sin(math.radians(lat))
    w = 1 - E2 * s * s
    return A * (1 - E2) / w**1.5, A / math.sqrt(w) * math.cos(math.radians(lat))


def place(lat: float, lon: float, dist: float, bearing: float) -> tuple[float, float]:
    """The point `dist` metres away at `bearing` (deg from north), on the tangent plane."""
    m, n = radii(lat)
    north = dist * math.cos(math.radians(bearing))
    east = dist * math.sin(math.radians(bearing))
    lon2 = lon + math.degrees(east / n)
    lon2 = (lon2 + 180.0) % 360.0 - 180.0
    return lat + math.degrees(north / m), lon2


def plane_range_bearing(lat: float, lon: float, lat2: float, lon2: float) -> tuple[float, float]:
    m, n = radii((lat + lat2) / 2)
    dlon = (lon2 - lon + 180.0) % 360.0 - 180.0
    north = math.radians(lat2 - lat) * m
    east = math.radians(dlon) * n
    return math.hypot(north, east), math.degrees(math.atan2(east, north)) % 360.0


# -- relative bearing ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("azimuth", "heading", "expected"),
    [
        (10, 350, 20),
        (350, 10, -20),
        (0, 0, 0),
        (180, 0, 180),
        (0, 180, 180),
        (359, 0, -1),
        (90, 270, 180),
        (45, -315, 0),
        (720, 0, 0),
    ],
)
def test_relative_bearing_is_clockwise_and_in_half_open_range(
    azimuth: float, heading: float, expected: float
) -> None:
    assert relative_bearing(azimuth, heading) == pytest.approx(expected)
    assert -180 < relative_bearing(azimuth, heading) <= 180


# -- one peer against the tangent plane ----------------------------------------------------------------


@pytest.mark.parametrize("lat", [0.0, 32.8, -45.0, 70.0])
def test_in_sector_range_and_bearing_match_the_tangent_plane(lat: float) -> None:
    rng = random.Random(7)
    for _ in range(50):
        lon = rng.uniform(-179.0, 179.0)
        heading = rng.uniform(0, 360)
        dist, bearing = rng.uniform(1, 150), rng.uniform(0, 360)
        plat, plon = place(lat, lon, dist, bearing)
        ref_d, ref_b = plane_range_bearing(lat, lon, plat, plon)
        inside, d, rel = in_sector(lat, lon, heading, plat, plon, 100.0, 60.0)
        assert d == pytest.approx(ref_d, abs=0.01)
        assert rel == pytest.approx(relative_bearing(ref_b, heading), abs=0.01)
        clearly_in = ref_d < 99.9 and abs(relative_bearing(ref_b, heading)) < 29.9
        clearly_out = ref_d > 100.1 or abs(relative_bearing(ref_b, heading)) > 30.1
        if clearly_in:
            assert inside
        if clearly_out:
            assert not inside


def test_coincident_peer_counts_as_dead_ahead() -> None:
    assert in_sector(32.0, 35.0, 123.0, 32.0, 35.0, 100.0, 60.0) == (True, 0.0, 0.0)


def test_sector_edges_are_inclusive_and_exact() -> None:
    lat, lon, heading = 32.0, 35.0, 350.0
    # Just inside and just outside the field of view's edge, and the range's.
    for rel, expect in ((29.9, True), (30.1, False), (-29.9, True), (-30.1, False)):
        plat, plon = place(lat, lon, 50.0, heading + rel)
        assert in_sector(lat, lon, heading, plat, plon, 100.0, 60.0)[0] is expect, rel
    for dist, expect in ((99.9, True), (100.1, False)):
        plat, plon = place(lat, lon, dist, heading)
        assert in_sector(lat, lon, heading, plat, plon, 100.0, 60.0)[0] is expect, dist


def test_heading_wraps_around_north() -> None:
    lat, lon = 32.0, 35.0
    plat, plon = place(lat, lon, 40.0, 10.0)  # absolute bearing 10°
    found = detect(lat, lon, 350.0, [(plat, plon)], 100.0, 60.0)
    assert found.detected and found.count == 1
    assert found.nearest_bearing == pytest.approx(20.0, abs=0.01)
    assert found.nearest_range == pytest.approx(40.0, abs=0.01)
    # and the mirror case: heading 10, peer at 350 → -20 (left)
    plat, plon = place(lat, lon, 40.0, 350.0)
    assert detect(lat, lon, 10.0, [(plat, plon)], 100.0, 60.0).nearest_bearing == pytest.approx(
        -20.0, abs=0.01
    )


def test_no_peer_gives_the_zero_answer() -> None:
    assert detect(32.0, 35.0, 0.0, [], 100.0, 60.0) == Detection(False, 0, 0.0, 0.0)


# -- shortcuts and index against brute force --------------------------------------------------------


def brute(
    lat: float, lon: float, heading: float, peers: list[tuple[float, float]], range_m: float, fov: float
) -> Detection:
    """`in_sector` on every peer: the definition `detect` must reproduce."""
    hits = []
    for plat, plon in peers:
        inside, d, rel = in_sector(lat, lon, heading, plat, plon, range_m, fov)
        if inside:
            hits.append((d, rel))
    if not hits:
        return Detection(False, 0, 0.0, 0.0)
    d, rel = min(hits)
    return Detection(True, len(hits), d, rel)


def same(a: Detection, b: Detection) -> bool:
    return (
        (a.detected, a.count) == (b.detected, b.count)
        and math.isclose(a.nearest_range, b.nearest_range, abs_tol=1e-9)
        and math.isclose(a.nearest_bearing, b.nearest_bearing, abs_tol=1e-9)
    )


SWARMS = [
    # (centre lat, centre lon, field half-width m, range m, fov deg, peers, reporters)
    (32.8, 35.0, 300.0, 100.0, 60.0, 150, 40),
    (-45.0, 170.0, 200.0, 50.0, 120.0, 150, 40),
    (70.0, -20.0, 400.0, 150.0, 10.0, 150, 40),
    (0.0, 179.999, 200.0, 100.0, 359.0, 150, 40),  # across the antimeridian
    (79.0, 100.0, 300.0, 120.0, 360.0, 150, 40),
    # Beyond the planar shortcut (latitude, range) and at the pole: every candidate solved exactly,
    # so fewer samples keep the test quick.
    (85.0, 0.0, 3000.0, 1500.0, 90.0, 60, 15),
    (10.0, 10.0, 20000.0, 8000.0, 45.0, 60, 15),
    (89.99, 45.0, 300.0, 200.0, 60.0, 60, 15),
]


@pytest.mark.parametrize(("clat", "clon", "half", "range_m", "fov", "n_peers", "n_reporters"), SWARMS)
def test_index_and_shortcuts_give_the_brute_force_answer(
    clat: float, clon: float, half: float, range_m: float, fov: float, n_peers: int, n_reporters: int
) -> None:
    rng = random.Random(int(abs(clat) * 1000 + abs(clon)))
    peers = []
    for _ in range(n_peers):
        # Clustered as well as spread, so that edges and ties get exercised.
        d = rng.uniform(0, half) if rng.random() < 0.7 else rng.uniform(0, range_m * 1.2)
        g = Geodesic.WGS84.Direct(clat, clon, rng.uniform(0, 360), d)
        peers.append((g["lat2"], (g["lon2"] + 180.0) % 360.0 - 180.0))
    index = GridIndex(range_m / 2)
    for i, (plat, plon) in enumerate(peers):
        index.update(i, plat, plon, 0.0)
    detected = 0
    for i in range(n_reporters):
        lat, lon = peers[i]
        heading = rng.uniform(-360, 720) % 360
        others = [p for j, p in enumerate(peers) if j != i]
        expected = brute(lat, lon, heading, others, range_m, fov)
        assert same(detect(lat, lon, heading, others, range_m, fov), expected)
        box = search_box(lat, lon, heading, range_m, fov)
        via_index = detect(lat, lon, heading, index.candidates(*box, exclude=i), range_m, fov)
        assert same(via_index, expected), (i, via_index, expected)
        detected += expected.detected
    assert detected > 0  # the swarm is dense enough for the comparison to mean something


def test_planar_error_stays_inside_the_margins_the_shortcut_assumes() -> None:
    """The shortcut classifies peers with a planar model; its documented bounds must hold."""
    rng = random.Random(3)
    for _ in range(2000):
        lat = rng.uniform(-sector._Flat.MAX_ABS_LAT, sector._Flat.MAX_ABS_LAT)
        lon = rng.uniform(-180, 180)
        dist = rng.uniform(sector._Flat.NEAR_M, sector._Flat.MAX_RANGE_M)
        az = rng.uniform(0, 360)
        flat = sector._Flat(lat, lon, az, dist, 60.0)
        g = Geodesic.WGS84.Direct(lat, lon, az, dist)
        dlon = (g["lon2"] - lon + 180.0) % 360.0 - 180.0
        north = (g["lat2"] - lat) * flat.k_north
        east = dlon * flat.k_east
        planar_d = math.hypot(north, east)
        planar_az = math.degrees(math.atan2(east, north))
        assert abs(planar_d - dist) <= 0.005 * dist
        assert abs(relative_bearing(planar_az, az)) <= 0.3


# -- the index itself ------------------------------------------------------------------------------


def test_grid_index_moves_removes_and_sweeps() -> None:
    index = GridIndex(50.0)
    index.update("a", 32.0, 35.0, 10.0)
    index.update("b", 32.0001, 35.0, 10.0)
    index.update("a", 32.01, 35.01, 11.0)  # moves to another cell
    box = (31.9, 32.1, 34.9, 35.1)
    assert sorted(index.candidates(*box)) == sorted([(32.01, 35.01), (32.0001, 35.0)])
    assert list(index.candidates(*box, exclude="a")) == [(32.0001, 35.0)]
    assert list(index.candidates(*box, since=10.5)) == [(32.01, 35.01)]
    assert index.sweep(older_than=10.5) == 1
    assert len(index) == 1 and "b" not in index
    index.remove("a")
    index.remove("a")
    assert len(index) == 0 and list(index.candidates(-90, 90, -180, 180)) == []


def test_search_box_contains_the_sector() -> None:
    rng = random.Random(11)
    for _ in range(300):
        lat, lon = rng.uniform(-80, 80), rng.uniform(-180, 180)
        heading, fov, rng_m = rng.uniform(0, 360), rng.uniform(1, 360), rng.uniform(5, 3000)
        south, north, west, east = search_box(lat, lon, heading, rng_m, fov)
        d = rng_m * rng.uniform(0, 1)
        b = heading + rng.uniform(-fov / 2, fov / 2)
        g = Geodesic.WGS84.Direct(lat, lon, b, d)
        plat, plon = g["lat2"], (g["lon2"] + 180.0) % 360.0 - 180.0
        assert south <= plat <= north
        if west <= east:
            assert west <= plon <= east
        else:
            assert plon >= west or plon <= east
