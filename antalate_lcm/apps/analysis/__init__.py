"""Looking at what a swarm did, from an LCM log: trajectories, state timelines, swarm metrics.

* :mod:`.logfile` reads a log (``lcm-logger``, ``antalate log``) into a :class:`SwarmRecord`; it is
  the only module here that touches files.
* :mod:`.metrics` computes, purely from that record, local east/north tracks (:mod:`.track`),
  cohesion over time and the centroid's drift against the commanded direction (definitions in its
  docstring), and gathers the swarm metrics of :mod:`.swarm` (radius, separation, nearest
  neighbours, polarisation, connectivity, crossings) per flight phase (:mod:`.phases`), built on
  the one-instant geometry of :mod:`.geometry`.
* :mod:`.safety` checks the log against a swarm's separation radius and fence (near-misses, breaches,
  the HLCs' SAFETY reports), when ``antalate analyze`` is given them (docs/safety.md).
* :mod:`.plot` draws one PNG (matplotlib, Agg backend).

``antalate analyze LOG`` and ``antalate plot LOG`` are thin wrappers around :func:`analyze_log`
and :func:`plot_log`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from antalate_lcm.apps.analysis.logfile import check_log_file, read_log
from antalate_lcm.apps.analysis.metrics import (
    DEFAULT_BIN_S,
    DEFAULT_MAX_AGE,
    Analysis,
    AnalysisOptions,
    CohesionSample,
    Drift,
    analyze,
    cohesion_at,
    cohesion_series,
    direction_spans,
    drift,
    format_summary,
    frame_origin,
    local_tracks,
)
from antalate_lcm.apps.analysis.phases import PHASES, FlightPhase, Window, flight_phases, mission_window
from antalate_lcm.apps.analysis.records import (
    AgentRecord,
    DirectionCommand,
    SafetyEvent,
    StateChange,
    SwarmRecord,
    TelemetrySample,
)
from antalate_lcm.apps.analysis.safety import Encounter, SafetyAnalysis, SafetyLimits, analyze_safety
from antalate_lcm.apps.analysis.swarm import (
    DEFAULT_MIN_SPEED,
    DEFAULT_RANGE_M,
    DEFAULT_STEP_S,
    Connectivity,
    Crossing,
    Distribution,
    Extent,
    PhaseMetrics,
    Separation,
    SwarmSample,
    phase_metrics,
    swarm_series,
)
from antalate_lcm.apps.analysis.track import Track

if TYPE_CHECKING:
    from typing_extensions import Unpack  # typing.Unpack is 3.11+


def default_plot_path(log: str | Path) -> Path:
    """``swarm.lcm`` -> ``swarm.png``; any other name gets ``.png`` appended, so lcm-logger's numbered
    files (``lcmlog-2026-11-22.00``, ``.01``) never share one plot."""
    p = Path(log)
    return p.with_suffix(".png") if p.suffix in (".lcm", ".mcap") else p.with_name(p.name + ".png")


def analyze_log(path: str | Path, **options: Unpack[AnalysisOptions]) -> Analysis:
    """Read ``path`` and analyse it (raises ``AntalateError`` for a file that is not a usable log).

    The options are :func:`analyze`'s. The result holds every agent's trajectory (``result.tracks``,
    metres north/east of ``result.origin``) beside the metrics.
    """
    return analyze(read_log(path), **options)


def plot_log(
    path: str | Path,
    out: str | Path | None = None,
    *,
    goals: Sequence[float] = (),
    **options: Unpack[AnalysisOptions],
) -> tuple[Path, Analysis]:
    """Read, analyse and plot ``path``; the PNG goes to ``out`` (default: :func:`default_plot_path`).

    ``goals`` are radii (m) drawn as horizontal lines on the cohesion panel (none by default: what
    counts as success depends on the algorithm); ``options`` are :func:`analyze`'s.
    """
    from antalate_lcm.apps.analysis.plot import plot

    record = read_log(path)
    result = analyze(record, **options)
    target = Path(out) if out is not None else default_plot_path(path)
    return plot(record, result, result.tracks, target, goals=goals), result


__all__ = [
    "DEFAULT_BIN_S",
    "DEFAULT_MAX_AGE",
    "DEFAULT_MIN_SPEED",
    "DEFAULT_RANGE_M",
    "DEFAULT_STEP_S",
    "PHASES",
    "AgentRecord",
    "Analysis",
    "AnalysisOptions",
    "CohesionSample",
    "Connectivity",
    "Crossing",
    "Distribution",
    "Extent",
    "FlightPhase",
    "PhaseMetrics",
    "Separation",
    "SwarmSample",
    "DirectionCommand",
    "Encounter",
    "SafetyAnalysis",
    "SafetyEvent",
    "SafetyLimits",
    "Drift",
    "StateChange",
    "SwarmRecord",
    "TelemetrySample",
    "Track",
    "Window",
    "analyze",
    "analyze_log",
    "analyze_safety",
    "check_log_file",
    "cohesion_at",
    "cohesion_series",
    "default_plot_path",
    "direction_spans",
    "drift",
    "flight_phases",
    "format_summary",
    "frame_origin",
    "local_tracks",
    "mission_window",
    "phase_metrics",
    "plot_log",
    "read_log",
    "swarm_series",
]
