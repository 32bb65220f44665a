"""A swarm's geofence: a simple polygon with a floor and a ceiling, as barrier constraints.

The polygon is given in the filter's local frame (metres north/east of the swarm origin; the config
converts WGS84 vertices). It may be concave. Each edge is a segment, and the distance from a point to
a segment is a convex function of the point, so -- as for separation (`antalate_lcm.base.safety.separation`)
-- the first-order constraint

    grad(dist_e) . u >= -gamma (dist_e - margin)

keeps ``dist_e >= margin`` for the sampled system too (``gamma dt <= 1``). An agent inside the polygon
cannot leave it without touching an edge, so keeping every edge at ``margin`` or more keeps it inside.
Floor and ceiling are the same constraint on the altitude. Only edges within `reach` of the margin are
turned into constraints: farther ones cannot bind at the vehicle's speed.

A vehicle found outside (it flew there before the filter was on, a gust, a bad position fix) is not
constrained but steered: `Geofence.way_back` is the direction to the nearest point of the fence
(inside by the margin), and the filter's policy says whether to fly it or land.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from antalate_lcm.base.safety.barrier import Constraint, Vec

Point = tuple[float, float]


def _segment_nearest(pn: float, pe: float, a: Point, b: Point) -> Point:
    dn, de = b[0] - a[0], b[1] - a[1]
    length2 = dn * dn + de * de
    t = 0.0 if length2 == 0.0 else max(0.0, min(1.0, ((pn - a[0]) * dn + (pe - a[1]) * de) / length2))
    return a[0] + t * dn, a[1] + t * de


def _cross(o: Point, a: Point, b: Point) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_cross(p1: Point, p2: Point, q1: Point, q2: Point) -> bool:
    """Proper or touching intersection of two segments."""
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    return d1 * d2 < 0 and d3 * d4 < 0


@dataclass(frozen=True)
class Geofence:
    """Where the swarm may fly: inside `polygon`, between `floor` and `ceiling` (m above home)."""

    polygon: tuple[Point, ...]
    floor: float
    ceiling: float
    #: m kept from every edge, the floor and the ceiling (the vehicle's stopping distance and GPS error).
    margin: float

    def __post_init__(self) -> None:
        pts = self.polygon
        if len(pts) < 3:
            raise ValueError(f"a geofence polygon needs at least 3 vertices, got {len(pts)}")
        for p in pts:
            if not all(math.isfinite(c) for c in p):
                raise ValueError(f"geofence vertex {p!r} is not finite")
        if not (math.isfinite(self.floor) and math.isfinite(self.ceiling) and self.floor < self.ceiling):
            raise ValueError(f"geofence floor {self.floor!r} must be below its ceiling {self.ceiling!r}")
        if not (math.isfinite(self.margin) and self.margin >= 0.0):
            raise ValueError(f"geofence margin must be >= 0, got {self.margin!r}")
        if 2 * self.margin >= self.ceiling - self.floor:
            raise ValueError(
                f"geofence margin {self.margin:g} m leaves no room between floor {self.floor:g} m"
                f" and ceiling {self.ceiling:g} m"
            )
        n = len(pts)
        area2 = sum(pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1] for i in range(n))
        if abs(area2) < 1e-6:
            raise ValueError("geofence polygon has no area (its vertices are on one line)")
        edges = self.edges
        for i in range(n):
            for j in range(i + 2, n):
                if i == 0 and j == n - 1:
                    continue  # neighbours through the closing vertex
                if _segments_cross(*edges[i], *edges[j]):
                    raise ValueError(f"geofence polygon crosses itself (edges {i} and {j})")

    @property
    def edges(self) -> list[tuple[Point, Point]]:
        pts = self.polygon
        return [(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]

    def inside_polygon(self, north: float, east: float) -> bool:
        """Even-odd rule (a ray towards +east)."""
        inside = False
        pts = self.polygon
        j = len(pts) - 1
        for i in range(len(pts)):
            (ni, ei), (nj, ej) = pts[i], pts[j]
            if (ni > north) != (nj > north):
                e_cross = ei + (north - ni) * (ej - ei) / (nj - ni)
                if east < e_cross:
                    inside = not inside
            j = i
        return inside

    def edge_distance(self, north: float, east: float) -> float:
        """Horizontal distance to the nearest edge."""
        best = math.inf
        for a, b in self.edges:
            qn, qe = _segment_nearest(north, east, a, b)
            best = min(best, math.hypot(north - qn, east - qe))
        return best

    def breach(self, north: float, east: float, up: float) -> str:
        """Why this point is outside the fence, "" when inside (margins not counted)."""
        if not self.inside_polygon(north, east):
            return f"outside the fence polygon by {self.edge_distance(north, east):.1f} m"
        if up > self.ceiling:
            return f"above the fence ceiling ({up:.1f} m > {self.ceiling:g} m)"
        if up < self.floor:
            return f"below the fence floor ({up:.1f} m < {self.floor:g} m)"
        return ""

    def constraints(
        self, north: float, east: float, up: float, gamma: float, reach: float, *, floor: bool = True
    ) -> list[Constraint]:
        """The constraints of the edges, floor and ceiling within `reach` of the margin.

        Call only for a point inside the polygon (see `breach`); `floor` False drops the floor (a
        vehicle that is landing must go through it).
        """
        out: list[Constraint] = []
        m = self.margin
        for i, (a, b) in enumerate(self.edges):
            qn, qe = _segment_nearest(north, east, a, b)
            dn, de = north - qn, east - qe
            d = math.hypot(dn, de)
            h = d - m
            if h > reach:
                continue
            if d < 1e-9:
                # On the edge: the inward normal of the edge (the polygon's orientation decides).
                en, ee = b[0] - a[0], b[1] - a[1]
                length = math.hypot(en, ee) or 1.0
                dn, de, d = -ee / length * self._orientation, en / length * self._orientation, 1.0
            # grad(dist) . u >= -gamma h   <=>   -grad . u <= gamma h
            out.append(Constraint((-dn / d, -de / d, 0.0), gamma * h, "fence", f"edge {i}"))
        if self.ceiling - m - up <= reach:
            out.append(Constraint((0.0, 0.0, 1.0), gamma * (self.ceiling - m - up), "fence", "ceiling"))
        if floor and up - self.floor - m <= reach:
            out.append(Constraint((0.0, 0.0, -1.0), gamma * (up - self.floor - m), "fence", "floor"))
        return out

    @property
    def _orientation(self) -> float:
        """+1 when the vertices run counter-clockwise in (north, east) coordinates, else -1."""
        pts = self.polygon
        n = len(pts)
        area2 = sum(pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1] for i in range(n))
        return 1.0 if area2 > 0 else -1.0

    def way_back(self, north: float, east: float, up: float) -> tuple[Vec, float]:
        """From a point outside: a unit vector (north, east, up) towards the inside, and how far to go
        (to the nearest point of the fence and the margin beyond it, at least 1 m: never "arrived" on the line)."""
        vn = ve = vu = 0.0
        far = 0.0
        if not self.inside_polygon(north, east):
            best = math.inf
            for a, b in self.edges:
                qn, qe = _segment_nearest(north, east, a, b)
                d = math.hypot(qn - north, qe - east)
                if d < best:
                    best, vn, ve = d, qn - north, qe - east
            far = best
        if up > self.ceiling - self.margin:
            vu = -1.0
            far = max(far, up - self.ceiling)
        elif up < self.floor + self.margin:
            vu = 1.0
            far = max(far, self.floor - up)
        norm = math.sqrt(vn * vn + ve * ve + vu * vu)
        if norm == 0.0:
            return (0.0, 0.0, 0.0), 0.0
        if vn or ve:
            # Horizontal distance dominates the way back; a vertical correction flies alongside.
            vn, ve = vn / math.hypot(vn, ve), ve / math.hypot(vn, ve)
            norm = math.sqrt(vn * vn + ve * ve + vu * vu)
        return (vn / norm, ve / norm, vu / norm), far + max(self.margin, 1.0)
