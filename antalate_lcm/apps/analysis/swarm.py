"""Swarm metrics for any algorithm, over time and per flight phase (pure: tracks in, numbers out).

Definitions (units: metres, seconds since the log's first event, m/s; the same in ``antalate
analyze``'s text and JSON, and in docs/logging.md):

* **Snapshot** at t: every agent heard within ``max_age`` s, at its position interpolated to t
  (:meth:`Track.position_at`), and its reported velocity (``telemetry_t.vn``/``ve``).
* **Radius**: the largest distance of an agent to the centroid; **mean distance**: the mean one.
* **Minimum separation**: the smallest distance between two agents, with when and which pair.
* **Nearest-neighbour distance**: each agent's distance to its nearest other agent; over a phase,
  the distribution of every agent's value at every sample (count, min, 10th percentile, median,
  mean, 90th percentile, max).
* **Polarisation** (the order parameter of Vicsek et al. 1995): the length of the mean of the
  moving agents' unit velocity vectors, 0..1 (1 = all aligned). Agents slower than ``min_speed``
  are left out; undefined with fewer than two moving.
* **Connectivity** at ``range_m``: the proximity graph joins two agents at most ``range_m`` apart;
  connected = one component. Per phase: the fraction of samples connected, the smallest largest
  component, and when the graph first split.
* **Crossings**: the first time in a phase the radius is below ``radius_below`` (converged) or
  above ``radius_above`` (dispersed or broken up), and how long after the phase's start.

A phase is sampled every ``step`` s from its start, and at its end, so start and end values are
exact and a crossing or a closest approach is placed within ``step``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from antalate_lcm.apps.analysis.geometry import (
    Point,
    centroid,
    closest_pair,
    components,
    nearest_neighbour_distances,
    polarisation,
    quantile,
)
from antalate_lcm.apps.analysis.phases import FlightPhase
from antalate_lcm.apps.analysis.track import Track

#: Sampling step of the per-phase metrics (s): the telemetry rate of the HLC (10 Hz).
DEFAULT_STEP_S = 0.1
#: Range of the proximity graph (m) when none is given.
DEFAULT_RANGE_M = 10.0
#: Below this speed (m/s) an agent has no heading for the polarisation.
DEFAULT_MIN_SPEED = 0.2


@dataclass(frozen=True)
class Snapshot:
    t: float
    points: dict[str, Point]
    velocities: dict[str, Point]


@dataclass(frozen=True)
class SwarmSample:
    """The swarm at one instant (the ``series`` of ``antalate analyze --json``)."""

    t: float
    agents: int
    radius: float
    mean_distance: float
    #: None below two agents.
    min_separation: float | None
    closest_pair: tuple[str, str] | None
    nn_mean: float | None
    polarisation: float | None
    components: int
    largest_component: int


@dataclass(frozen=True)
class Extent:
    """A quantity over a phase: its value at the start and the end, its extremes and when, its mean."""

    start: float
    end: float
    min: float
    min_t: float
    max: float
    max_t: float
    mean: float


@dataclass(frozen=True)
class Separation:
    distance: float
    t: float
    a: str
    b: str


@dataclass(frozen=True)
class Distribution:
    count: int
    min: float
    p10: float
    median: float
    mean: float
    p90: float
    max: float


@dataclass(frozen=True)
class Connectivity:
    range_m: float
    #: Fraction of the phase's samples in which the proximity graph was one component.
    connected_fraction: float
    #: The smallest "largest component" (agents) seen, and when.
    min_largest: int
    min_largest_t: float
    #: When the graph first had more than one component; None if it never split.
    first_split_t: float | None


@dataclass(frozen=True)
class Crossing:
    threshold: float
    #: When it first happened (s since the log's start) and how long after the phase's start;
    #: both None when it never happened in the phase.
    t: float | None
    after: float | None


@dataclass(frozen=True)
class PhaseMetrics:
    phase: FlightPhase
    samples: int
    radius: Extent | None
    mean_distance: Extent | None
    min_separation: Separation | None
    nearest_neighbour: Distribution | None
    polarisation: Extent | None
    connectivity: Connectivity | None
    #: Only when a threshold was asked for.
    radius_below: Crossing | None = None
    radius_above: Crossing | None = None


def snapshot(tracks: Mapping[str, Track], t: float, max_age: float) -> Snapshot:
    points: dict[str, Point] = {}
    velocities: dict[str, Point] = {}
    for name, track in tracks.items():
        p = track.position_at(t, max_age)
        if p is None:
            continue
        points[name] = p
        v = track.velocity_at(t, max_age)
        if v is not None:
            velocities[name] = v
    return Snapshot(t, points, velocities)


def swarm_sample(
    snap: Snapshot, range_m: float = DEFAULT_RANGE_M, min_speed: float = DEFAULT_MIN_SPEED
) -> SwarmSample | None:
    """The metrics of one snapshot; None when no agent is heard."""
    points = snap.points
    if not points:
        return None
    cn, ce = centroid(points)
    dists = [math.hypot(p[0] - cn, p[1] - ce) for p in points.values()]
    pair = closest_pair(points)
    nn = nearest_neighbour_distances(points)
    groups = components(points, range_m)
    return SwarmSample(
        snap.t,
        len(points),
        max(dists),
        sum(dists) / len(dists),
        pair[0] if pair else None,
        (pair[1], pair[2]) if pair else None,
        sum(nn.values()) / len(nn) if nn else None,
        polarisation(list(snap.velocities.values()), min_speed),
        len(groups),
        len(groups[0]),
    )


def sample_times(start: float, end: float, step: float) -> list[float]:
    """``start``, every ``step`` after it, and ``end`` (once, even when it falls on the grid)."""
    if step <= 0:
        raise ValueError("step must be > 0")
    n = int(math.floor((end - start) / step + 1e-9))
    times = [start + k * step for k in range(n + 1)]
    if end - times[-1] > 1e-9:
        times.append(end)
    return times


def swarm_series(
    tracks: Mapping[str, Track],
    start: float,
    end: float,
    step: float,
    max_age: float,
    range_m: float = DEFAULT_RANGE_M,
    min_speed: float = DEFAULT_MIN_SPEED,
) -> list[SwarmSample]:
    """:func:`swarm_sample` at :func:`sample_times` (instants where nobody is heard are left out)."""
    out = []
    for t in sample_times(start, end, step):
        s = swarm_sample(snapshot(tracks, t, max_age), range_m, min_speed)
        if s is not None:
            out.append(s)
    return out


def extent(times: list[float], values: list[float]) -> Extent | None:
    if not values:
        return None
    lo = min(range(len(values)), key=lambda i: values[i])
    hi = max(range(len(values)), key=lambda i: values[i])
    return Extent(
        values[0], values[-1], values[lo], times[lo], values[hi], times[hi], sum(values) / len(values)
    )


def distribution(values: list[float]) -> Distribution | None:
    if not values:
        return None
    v = sorted(values)
    return Distribution(
        len(v), v[0], quantile(v, 0.1), quantile(v, 0.5), sum(v) / len(v), quantile(v, 0.9), v[-1]
    )


def first_crossing(
    times: list[float], values: list[float], threshold: float, *, below: bool, since: float
) -> Crossing:
    """The first sample strictly below (or above) ``threshold``."""
    for t, v in zip(times, values, strict=True):
        if (v < threshold) if below else (v > threshold):
            return Crossing(threshold, t, t - since)
    return Crossing(threshold, None, None)


def phase_metrics(
    tracks: Mapping[str, Track],
    phase: FlightPhase,
    *,
    step: float = DEFAULT_STEP_S,
    max_age: float,
    range_m: float = DEFAULT_RANGE_M,
    min_speed: float = DEFAULT_MIN_SPEED,
    radius_below: float | None = None,
    radius_above: float | None = None,
) -> PhaseMetrics:
    """Every metric of the module docstring over ``phase``."""
    snaps = [snapshot(tracks, t, max_age) for t in sample_times(phase.start, phase.end, step)]
    snaps = [s for s in snaps if s.points]
    samples = [s for s in (swarm_sample(s, range_m, min_speed) for s in snaps) if s is not None]
    times = [s.t for s in samples]
    radius = [s.radius for s in samples]
    closest: Separation | None = None
    for s in samples:
        if (
            s.min_separation is not None
            and s.closest_pair is not None
            and (closest is None or s.min_separation < closest.distance)
        ):
            closest = Separation(s.min_separation, s.t, *s.closest_pair)
    nn_all = [d for snap in snaps for d in nearest_neighbour_distances(snap.points).values()]
    pol = [(s.t, s.polarisation) for s in samples if s.polarisation is not None]
    connectivity = None
    if samples:
        small = min(samples, key=lambda s: s.largest_component)
        split = next((s.t for s in samples if s.components > 1), None)
        connectivity = Connectivity(
            range_m,
            sum(1 for s in samples if s.components == 1) / len(samples),
            small.largest_component,
            small.t,
            split,
        )
    return PhaseMetrics(
        phase,
        len(samples),
        extent(times, radius),
        extent(times, [s.mean_distance for s in samples]),
        closest,
        distribution(nn_all),
        extent([t for t, _ in pol], [p for _, p in pol]),
        connectivity,
        first_crossing(times, radius, radius_below, below=True, since=phase.start)
        if radius_below is not None
        else None,
        first_crossing(times, radius, radius_above, below=False, since=phase.start)
        if radius_above is not None
        else None,
    )


def _extent_line(label: str, e: Extent | None, fmt: str, unit: str) -> str:
    if e is None:
        return f"  {label:<18} -"
    return (
        f"  {label:<18} start {e.start:{fmt}}  end {e.end:{fmt}}  min {e.min:{fmt}} @{e.min_t:.1f} s  "
        f"max {e.max:{fmt}} @{e.max_t:.1f} s  mean {e.mean:{fmt}}{unit}"
    )


def _crossing_line(label: str, c: Crossing | None) -> list[str]:
    if c is None:
        return []
    if c.t is None or c.after is None:
        return [f"  {label} {c.threshold:g} m: never"]
    return [f"  {label} {c.threshold:g} m: after {c.after:.1f} s (at {c.t:.1f} s)"]


def format_phase(m: PhaseMetrics) -> list[str]:
    """The text of one phase in ``antalate analyze``'s summary."""
    p = m.phase
    lines = [
        f"phase {p.name}: {p.start:.1f} .. {p.end:.1f} s ({p.length:.1f} s; {p.how}); {m.samples} samples"
    ]
    if not m.samples:
        return [*lines, "  no agent heard"]
    lines.append(_extent_line("radius", m.radius, ".1f", " m"))
    lines.append(_extent_line("mean distance", m.mean_distance, ".1f", " m"))
    lines += _crossing_line("radius first below", m.radius_below)
    lines += _crossing_line("radius first above", m.radius_above)
    s = m.min_separation
    lines.append(
        f"  {'min separation':<18} {s.distance:.2f} m at {s.t:.1f} s ({s.a}, {s.b})"
        if s
        else f"  {'min separation':<18} - (fewer than two agents)"
    )
    d = m.nearest_neighbour
    if d is not None:
        lines.append(
            f"  {'nearest neighbour':<18} min {d.min:.2f}  p10 {d.p10:.2f}  median {d.median:.2f}  "
            f"mean {d.mean:.2f}  p90 {d.p90:.2f}  max {d.max:.2f} m ({d.count} values)"
        )
    lines.append(
        _extent_line("polarisation", m.polarisation, ".2f", "")
        if m.polarisation
        else f"  {'polarisation':<18} - (fewer than two agents moving)"
    )
    c = m.connectivity
    if c is not None:
        split = f"first split at {c.first_split_t:.1f} s" if c.first_split_t is not None else "never split"
        lines.append(
            f"  {f'connectivity {c.range_m:g} m':<18} connected in {100 * c.connected_fraction:.0f} % of the "
            f"samples; largest component at least {c.min_largest} agent(s) (at {c.min_largest_t:.1f} s); {split}"
        )
    return lines
