"""The geometry of one instant of a swarm (pure: points in, numbers out; no time, no files).

A *snapshot* is ``{agent: (north, east)}`` in metres, plus optionally ``{agent: (vn, ve)}`` in m/s.
Every distance is horizontal: the analysis works in the local north/east plane, where swarm rules
act (the agents of one swarm fly at one altitude; the altitude is on the tracks for whoever needs it).

Pairwise work is O(N²) per snapshot: 45 pairs for 10 agents, 5,000 for 100; a thousand agents take
half a million distances per sample, which is why the series are sampled, not computed at every
telemetry message.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

Point = tuple[float, float]


def centroid(points: Mapping[str, Point]) -> Point:
    """The mean position (the caller ensures there is at least one point)."""
    n = len(points)
    return sum(p[0] for p in points.values()) / n, sum(p[1] for p in points.values()) / n


def closest_pair(points: Mapping[str, Point]) -> tuple[float, str, str] | None:
    """The smallest pairwise distance and the two agents (names sorted); None below two agents.

    Ties go to the pair whose names sort first, so a result is reproducible run to run.
    """
    names = sorted(points)
    best: tuple[float, str, str] | None = None
    for i, a in enumerate(names):
        pa = points[a]
        for b in names[i + 1 :]:
            pb = points[b]
            d = math.hypot(pa[0] - pb[0], pa[1] - pb[1])
            if best is None or d < best[0]:
                best = (d, a, b)
    return best


def nearest_neighbour_distances(points: Mapping[str, Point]) -> dict[str, float]:
    """Each agent's distance to its nearest other agent (empty below two agents)."""
    if len(points) < 2:
        return {}
    out: dict[str, float] = {}
    items = list(points.items())
    for a, pa in items:
        out[a] = min(math.hypot(pa[0] - pb[0], pa[1] - pb[1]) for b, pb in items if b != a)
    return out


def polarisation(velocities: Sequence[Point], min_speed: float) -> float | None:
    """The order parameter: the length of the mean of the agents' unit velocity vectors, in [0, 1].

    1 = every agent flies the same way; about 1/sqrt(N) for random headings; 0 for a perfect
    mill. Agents slower than ``min_speed`` have no meaningful heading and are left out; None when
    fewer than two agents are moving (the measure needs at least two to compare).
    """
    units = []
    for vn, ve in velocities:
        s = math.hypot(vn, ve)
        if s >= min_speed and s > 0:
            units.append((vn / s, ve / s))
    if len(units) < 2:
        return None
    sn = sum(u[0] for u in units) / len(units)
    se = sum(u[1] for u in units) / len(units)
    return min(1.0, math.hypot(sn, se))


def components(points: Mapping[str, Point], range_m: float) -> list[set[str]]:
    """Connected components of the proximity graph (an edge between agents at most ``range_m`` apart),
    largest first (ties by their first name)."""
    names = sorted(points)
    seen: set[str] = set()
    out: list[set[str]] = []
    for start in names:
        if start in seen:
            continue
        group = {start}
        stack = [start]
        seen.add(start)
        while stack:
            a = stack.pop()
            pa = points[a]
            for b in names:
                if b in seen:
                    continue
                pb = points[b]
                if math.hypot(pa[0] - pb[0], pa[1] - pb[1]) <= range_m:
                    seen.add(b)
                    group.add(b)
                    stack.append(b)
        out.append(group)
    out.sort(key=lambda g: (-len(g), min(g)))
    return out


def quantile(sorted_values: Sequence[float], q: float) -> float:
    """Linear-interpolation quantile (numpy's default) of an already sorted, non-empty sequence."""
    if not 0.0 <= q <= 1.0:
        raise ValueError("q must be in [0, 1]")
    pos = q * (len(sorted_values) - 1)
    lo = math.floor(pos)
    hi = min(lo + 1, len(sorted_values) - 1)
    return sorted_values[lo] + (pos - lo) * (sorted_values[hi] - sorted_values[lo])
