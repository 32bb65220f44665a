"""Swarm metrics from a decoded log (pure: no files, no clock; everything is a function of the record).

Frame: positions are metres north/east of an origin, the mean of the agents' first fixes, computed
with the exact geodesic :func:`antalate_lcm.base.geo.local_ne` (about 50 µs a sample: a 10-agent,
10 Hz, 5-minute log takes a couple of seconds; exactness matters more here than in the simulator,
since these numbers are what people compare).

Definitions (also printed by ``antalate analyze``):

* **Mission window**: from the moment the *last* agent entered MISSION to the moment the *first*
  one left it (or the end of the log): the span in which the whole swarm was flying its mission.
  Without MC states in the log, the span in which every agent's telemetry says ``in_air``.
* **Cohesion** at time t: the centroid of the agents heard within ``max_age`` s, and the mean and
  the maximum distance of those agents to it. The maximum is the swarm's *radius* (the smallest
  circle around the centroid holding every agent). Sampled every ``bin_s`` seconds, from the moment
  every agent in the log had been heard once.
* **Cohesion ratio**: the largest radius in the mission window over the radius at its start.
* **Drift**: the centroid's displacement over each span of one commanded direction inside the
  window (its heading, distance and speed), against the commanded azimuth; the error is signed,
  in (-180, 180], positive = clockwise of the command. The centroid is taken over the agents heard
  at both ends, so an agent dropping out does not look like a swarm moving.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, TypedDict

from antalate_lcm.apps.analysis.phases import Window, flight_phases, mission_window
from antalate_lcm.apps.analysis.records import DirectionCommand, FaultRecord, SwarmRecord
from antalate_lcm.apps.analysis.safety import SafetyAnalysis, SafetyLimits, analyze_safety, format_safety
from antalate_lcm.apps.analysis.swarm import (
    DEFAULT_MIN_SPEED,
    DEFAULT_RANGE_M,
    DEFAULT_STEP_S,
    PhaseMetrics,
    SwarmSample,
    format_phase,
    phase_metrics,
    sample_times,
    swarm_series,
)
from antalate_lcm.apps.analysis.track import Track
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.base.geo import local_ne, wrap_180, wrap_360

#: Default sampling period of the cohesion series (s).
DEFAULT_BIN_S = 1.0
#: A position older than this (s) no longer counts: the agent is silent (stale, cut off, landed).
DEFAULT_MAX_AGE = 2.0
#: Below this centroid displacement (m) a drift has no meaningful heading.
MIN_DRIFT_M = 0.5


@dataclass(frozen=True)
class CohesionSample:
    t: float
    agents: int
    centroid_north: float
    centroid_east: float
    mean_distance: float
    max_distance: float


@dataclass(frozen=True)
class Drift:
    start: float
    end: float
    #: The commanded azimuth (deg) and speed (m/s; None when given with --azimuth only).
    azimuth: float
    commanded_speed: float | None
    agents: int
    #: Centroid displacement: heading (deg, None when too short to have one), metres, m/s.
    heading: float | None
    distance: float
    speed: float
    #: heading - azimuth in (-180, 180]; None without a heading.
    error: float | None
    #: Where the command came from: "log" (direction_cmd_t) or "option" (--azimuth).
    source: str


@dataclass
class Analysis:
    path: str
    origin: tuple[float, float]
    agents: list[str]
    duration: float
    events: int
    window: Window | None
    cohesion: list[CohesionSample] = field(default_factory=list)
    start_radius: float | None = None
    peak_radius: float | None = None
    peak_radius_t: float | None = None
    start_mean: float | None = None
    average_mean: float | None = None
    drift: list[Drift] = field(default_factory=list)
    mc_timelines: dict[str, list[tuple[float, str]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: The swarm metrics of each flight phase (takeoff, mission, return; analysis/swarm.py).
    phases: list[PhaseMetrics] = field(default_factory=list)
    #: The swarm metrics every ``bin_s`` s over the whole log.
    series: list[SwarmSample] = field(default_factory=list)
    #: The faults an experiment's script injected, in the order they happened (with broadcast reception).
    faults: list[FaultRecord] = field(default_factory=list)
    #: Every agent's trajectory in the local frame (left out of :meth:`to_json` unless asked for).
    tracks: dict[str, Track] = field(default_factory=dict)
    #: Separation, near-misses, fence breaches and SAFETY reports (analysis/safety.py), when limits were given.
    safety: SafetyAnalysis | None = None

    def phase(self, name: str) -> PhaseMetrics | None:
        """The metrics of the phase called ``name`` ("takeoff", "mission", "return"), if the log has it."""
        return next((p for p in self.phases if p.phase.name == name), None)

    @property
    def cohesion_ratio(self) -> float | None:
        if self.start_radius is None or self.peak_radius is None or self.start_radius <= 0:
            return None
        return self.peak_radius / self.start_radius

    def to_json(self, *, tracks: bool = False) -> dict[str, Any]:
        """Everything, as plain JSON types (``antalate analyze --json``); the trajectories only with
        ``tracks`` (they are most of the bytes: 60 numbers a second an agent)."""
        out = asdict(self)
        if not tracks:
            del out["tracks"]
        out["cohesion_ratio"] = self.cohesion_ratio
        out["origin"] = {"lat": self.origin[0], "lon": self.origin[1]}
        out["mc_timelines"] = {
            a: [{"t": t, "state": s} for t, s in tl] for a, tl in self.mc_timelines.items()
        }
        return out


# ----------------------------------------------------------------------------- building blocks
def frame_origin(record: SwarmRecord) -> tuple[float, float]:
    """The mean of the agents' first fixes: the swarm's start sits near (0, 0) on the plots."""
    firsts = [rec.telemetry[0] for rec in record.agents.values() if rec.telemetry]
    if not firsts:
        raise AntalateError(f"{record.path}: no telemetry in this log ({_what_it_holds(record)})")
    return sum(s.lat for s in firsts) / len(firsts), sum(s.lon for s in firsts) / len(firsts)


def local_tracks(record: SwarmRecord, origin: tuple[float, float]) -> dict[str, Track]:
    """Every agent's telemetry as metres north/east of ``origin`` (agents without telemetry left out)."""
    lat0, lon0 = origin
    tracks: dict[str, Track] = {}
    for name, rec in sorted(record.agents.items()):
        samples = sorted(rec.telemetry, key=lambda s: s.t)
        if not samples:
            continue
        ne = [local_ne(lat0, lon0, s.lat, s.lon) for s in samples]
        tracks[name] = Track(
            [s.t for s in samples],
            [p[0] for p in ne],
            [p[1] for p in ne],
            [s.alt for s in samples],
            [s.vn for s in samples],
            [s.ve for s in samples],
        )
    return tracks


def cohesion_at(
    tracks: dict[str, Track], t: float, max_age: float = DEFAULT_MAX_AGE, agents: set[str] | None = None
) -> CohesionSample | None:
    """Centroid and spread of the agents heard at ``t`` (only ``agents`` if given); None if none is."""
    points = []
    for name, track in tracks.items():
        if agents is not None and name not in agents:
            continue
        p = track.position_at(t, max_age)
        if p is not None:
            points.append(p)
    if not points:
        return None
    cn = sum(p[0] for p in points) / len(points)
    ce = sum(p[1] for p in points) / len(points)
    dists = [math.hypot(p[0] - cn, p[1] - ce) for p in points]
    return CohesionSample(t, len(points), cn, ce, sum(dists) / len(dists), max(dists))


def cohesion_series(
    tracks: dict[str, Track],
    start: float,
    end: float,
    bin_s: float = DEFAULT_BIN_S,
    max_age: float = DEFAULT_MAX_AGE,
) -> list[CohesionSample]:
    """:func:`cohesion_at` every ``bin_s`` seconds from ``start`` to ``end`` (both included)."""
    if bin_s <= 0:
        raise ValueError("bin_s must be > 0")
    samples = (cohesion_at(tracks, t, max_age) for t in sample_times(start, end, bin_s))
    return [s for s in samples if s is not None]


def direction_spans(
    directions: list[DirectionCommand], window: Window
) -> list[tuple[float, float, DirectionCommand]]:
    """The spans of the window under one active broadcast direction command each.

    Commands for a single agent are left out: they do not move the swarm's centroid as a whole.
    """
    swarm = sorted((d for d in directions if not d.target), key=lambda d: d.t)
    out = []
    for i, cmd in enumerate(swarm):
        if not cmd.active:
            continue
        until = swarm[i + 1].t if i + 1 < len(swarm) else math.inf
        start, end = max(cmd.t, window.start), min(until, window.end)
        if end > start:
            out.append((start, end, cmd))
    return out


def drift(
    tracks: dict[str, Track],
    start: float,
    end: float,
    azimuth: float,
    commanded_speed: float | None,
    source: str,
    max_age: float = DEFAULT_MAX_AGE,
) -> Drift | None:
    """The centroid's motion from ``start`` to ``end`` against ``azimuth`` (agents heard at both ends)."""
    both = {
        name
        for name, tr in tracks.items()
        if tr.position_at(start, max_age) is not None and tr.position_at(end, max_age) is not None
    }
    a = cohesion_at(tracks, start, max_age, both)
    b = cohesion_at(tracks, end, max_age, both)
    if a is None or b is None:
        return None
    dn, de = b.centroid_north - a.centroid_north, b.centroid_east - a.centroid_east
    dist = math.hypot(dn, de)
    heading = wrap_360(math.degrees(math.atan2(de, dn))) if dist >= MIN_DRIFT_M else None
    error = None
    if heading is not None:
        error = wrap_180(heading - azimuth)
        if error == -180.0:
            error = 180.0
    return Drift(
        start,
        end,
        wrap_360(azimuth),
        commanded_speed,
        len(both),
        heading,
        dist,
        dist / (end - start) if end > start else 0.0,
        error,
        source,
    )


# ----------------------------------------------------------------------------- the whole analysis
class AnalysisOptions(TypedDict, total=False):
    """The keywords of :func:`analyze`, typed once for what passes them on (``analyze_log``,
    ``plot_log``, the CLI's options): a caller of those gets the same checking as one of ``analyze``."""

    azimuth: float | None
    bin_s: float
    max_age: float
    step: float
    range_m: float
    min_speed: float
    radius_below: float | None
    radius_above: float | None
    safety: SafetyLimits | None


def analyze(
    record: SwarmRecord,
    *,
    azimuth: float | None = None,
    bin_s: float = DEFAULT_BIN_S,
    max_age: float = DEFAULT_MAX_AGE,
    step: float = DEFAULT_STEP_S,
    range_m: float = DEFAULT_RANGE_M,
    min_speed: float = DEFAULT_MIN_SPEED,
    radius_below: float | None = None,
    radius_above: float | None = None,
    safety: SafetyLimits | None = None,
) -> Analysis:
    """Cohesion over time, the mission window's cohesion ratio, the drift against the command, and
    the swarm metrics of :mod:`.swarm` over time and per flight phase; with `safety`, the checks of
    :mod:`.safety` against those limits.

    ``azimuth`` overrides the log's direction commands (for logs recorded without the operator's
    channels, or to ask how far the swarm went in some other direction). ``step``, ``range_m``,
    ``min_speed``, ``radius_below`` and ``radius_above`` are :func:`.swarm.phase_metrics`'s.
    """
    origin = frame_origin(record)
    tracks = local_tracks(record, origin)
    # From the moment every agent had been heard: before that the "swarm" is whoever spoke first
    # (one agent has radius 0), which says nothing about cohesion.
    t_first = max(tr.t[0] for tr in tracks.values())
    t_last = max(tr.t[-1] for tr in tracks.values())
    result = Analysis(
        path=record.path,
        origin=origin,
        agents=sorted(tracks),
        duration=record.duration,
        events=record.events,
        window=mission_window(record),
        mc_timelines={a: [(c.t, c.state) for c in r.mc_states] for a, r in sorted(record.agents.items())},
        faults=list(record.faults),
    )
    result.cohesion = cohesion_series(tracks, t_first, t_last, bin_s, max_age)
    result.tracks = tracks
    result.series = swarm_series(tracks, t_first, t_last, bin_s, max_age, range_m, min_speed)
    result.phases = [
        phase_metrics(
            tracks,
            phase,
            step=step,
            max_age=max_age,
            range_m=range_m,
            min_speed=min_speed,
            radius_below=radius_below,
            radius_above=radius_above,
        )
        for phase in flight_phases(record, result.window)
    ]
    if safety is not None:
        result.safety = analyze_safety(record, safety, origin, step=step, max_age=max_age)
    window = result.window
    if window is None:
        result.notes.append("no mission window: the swarm never flew a mission together")
    else:
        inside = [c for c in result.cohesion if window.start <= c.t <= window.end]
        first = cohesion_at(tracks, window.start, max_age)
        if first is not None:
            inside = [first, *(c for c in inside if c.t > first.t)]
        if inside:
            result.start_radius = inside[0].max_distance
            result.start_mean = inside[0].mean_distance
            peak = max(inside, key=lambda c: c.max_distance)
            result.peak_radius, result.peak_radius_t = peak.max_distance, peak.t
            result.average_mean = sum(c.mean_distance for c in inside) / len(inside)
        if azimuth is not None:
            d = drift(tracks, window.start, window.end, azimuth, None, "option", max_age)
            if d is not None:
                result.drift.append(d)
        else:
            spans = direction_spans(record.directions, window)
            for start, end, cmd in spans:
                d = drift(tracks, start, end, cmd.azimuth, cmd.speed, "log", max_age)
                if d is not None:
                    result.drift.append(d)
            if not spans:
                result.notes.append(
                    "no active direction command for the whole swarm in the mission window "
                    "(pass --azimuth to compare the drift with a direction)"
                )
    if record.truncated:
        result.notes.append(record.truncated)
    if record.skipped:
        result.notes.append(
            f"skipped {record.skipped} event(s): {sum(record.undecodable.values())} undecodable on antalate "
            f"channels, {sum(record.unknown.values())} on {len(record.unknown)} unknown channel(s)"
        )
    return result


def _what_it_holds(record: SwarmRecord) -> str:
    if not record.events:
        return "it holds no events"
    parts = [f"{record.events} event(s)"]
    if record.unknown:
        parts.append(f"{len(record.unknown)} non-antalate channel(s)")
    if record.undecodable:
        parts.append(f"{sum(record.undecodable.values())} undecodable")
    return ", ".join(parts)


def format_summary(a: Analysis) -> str:
    """The human-readable report of ``antalate analyze``."""
    lines = [
        f"log: {a.path}",
        f"  {a.events} events over {a.duration:.1f} s; {len(a.agents)} agent(s) with telemetry: "
        + ", ".join(a.agents),
        f"  frame origin (mean first fix): {a.origin[0]:.6f}, {a.origin[1]:.6f}",
    ]
    lines.append("MC state timelines (s since the log's start):")
    for agent, timeline in a.mc_timelines.items():
        lines.append(f"  {agent}: " + (" -> ".join(f"{s}@{t:.1f}" for t, s in timeline) or "(no MC state)"))
    if a.window is not None:
        w = a.window
        lines.append(f"mission window: {w.start:.1f} s .. {w.end:.1f} s ({w.length:.1f} s; {w.how})")
    else:
        lines.append("mission window: none")
    if a.start_radius is not None and a.peak_radius is not None:
        ratio = a.cohesion_ratio
        lines.append(
            f"cohesion: radius (max distance to the centroid) {a.start_radius:.1f} m at the start, "
            f"peak {a.peak_radius:.1f} m at {a.peak_radius_t:.1f} s"
            + (f" = {ratio:.2f} x the starting radius" if ratio is not None else "")
        )
        lines.append(
            f"          mean distance to the centroid {a.start_mean:.1f} m at the start, "
            f"{a.average_mean:.1f} m on average over the window"
        )
    lines += [line for m in a.phases for line in format_phase(m)]
    for d in a.drift:
        cmd = f"commanded {d.azimuth:.0f} deg" + (
            f" at {d.commanded_speed:g} m/s" if d.commanded_speed else ""
        )
        cmd += " (from the log)" if d.source == "log" else " (--azimuth)"
        if d.heading is None:
            lines.append(
                f"drift {d.start:.1f}..{d.end:.1f} s: centroid moved only {d.distance:.2f} m ({cmd}): no heading"
            )
        else:
            lines.append(
                f"drift {d.start:.1f}..{d.end:.1f} s: centroid heading {d.heading:.1f} deg, {d.distance:.1f} m at "
                f"{d.speed:.2f} m/s over {d.agents} agent(s); {cmd}; error {d.error:+.1f} deg"
            )
    if a.safety is not None:
        lines += format_safety(a.safety)
    lines += format_faults(a.faults)
    lines.extend(f"note: {n}" for n in a.notes)
    return "\n".join(lines)


def format_faults(faults: list[FaultRecord]) -> list[str]:
    """The faults of the log, one line each (s since the log's start)."""
    if not faults:
        return []
    lines = ["faults injected by the experiment's script (s since the log's start):"]
    for f in faults:
        if f.kind == "broadcast":
            heard, offered = f.detail.get("heard"), f.detail.get("offered")
            lines.append(
                f"  broadcast reception {f.agent}: heard {heard} of {offered} (p = {f.detail.get('reception')})"
            )
            continue
        extra = ", ".join(f"{k} {v}" for k, v in sorted(f.detail.items()) if k not in ("at", "fault"))
        lines.append(f"  {f.t:7.1f}  {f.kind} {f.event:<6} {f.agent}" + (f" ({extra})" if extra else ""))
    return lines
