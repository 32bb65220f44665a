"""Looking at what a swarm did, from an LCM log: trajectories, state timelines, swarm metrics.

* :mod:`.logfile` reads a log (``lcm-logger``, ``antalate log``) into a :class:`SwarmRecord`; it is
  the only module here that touches files.
* :mod:`.metrics` computes, purely from that record, local east/north tracks, cohesion over time
  and the centroid's drift against the commanded direction (definitions in its docstring).
* :mod:`.plot` draws one PNG (matplotlib, Agg backend).

``antalate analyze LOG`` and ``antalate plot LOG`` are thin wrappers around :func:`analyze_log`
and :func:`plot_log`.
"""

from __future__ import annotations

from pathlib import Path

from antalate_lcm.analysis.logfile import check_log_file, read_log
from antalate_lcm.analysis.metrics import (
    DEFAULT_BIN_S,
    DEFAULT_MAX_AGE,
    Analysis,
    CohesionSample,
    Drift,
    Track,
    Window,
    analyze,
    cohesion_at,
    cohesion_series,
    direction_spans,
    drift,
    format_summary,
    frame_origin,
    local_tracks,
    mission_window,
)
from antalate_lcm.analysis.model import (
    AgentRecord,
    DirectionCommand,
    StateChange,
    SwarmRecord,
    TelemetrySample,
)


def default_plot_path(log: str | Path) -> Path:
    """``swarm.lcm`` -> ``swarm.png``; any other name gets ``.png`` appended, so lcm-logger's numbered
    files (``lcmlog-2026-11-22.00``, ``.01``) never share one plot."""
    p = Path(log)
    return p.with_suffix(".png") if p.suffix in (".lcm", ".mcap") else p.with_name(p.name + ".png")


def analyze_log(
    path: str | Path,
    *,
    azimuth: float | None = None,
    bin_s: float = DEFAULT_BIN_S,
    max_age: float = DEFAULT_MAX_AGE,
) -> Analysis:
    """Read ``path`` and analyse it (raises ``AntalateError`` for a file that is not a usable log)."""
    return analyze(read_log(path), azimuth=azimuth, bin_s=bin_s, max_age=max_age)


def plot_log(
    path: str | Path,
    out: str | Path | None = None,
    *,
    azimuth: float | None = None,
    bin_s: float = DEFAULT_BIN_S,
    max_age: float = DEFAULT_MAX_AGE,
) -> tuple[Path, Analysis]:
    """Read, analyse and plot ``path``; the PNG goes to ``out`` (default: :func:`default_plot_path`)."""
    from antalate_lcm.analysis.plot import plot

    record = read_log(path)
    result = analyze(record, azimuth=azimuth, bin_s=bin_s, max_age=max_age)
    tracks = local_tracks(record, result.origin)
    target = Path(out) if out is not None else default_plot_path(path)
    return plot(record, result, tracks, target), result


__all__ = [
    "DEFAULT_BIN_S",
    "DEFAULT_MAX_AGE",
    "AgentRecord",
    "Analysis",
    "CohesionSample",
    "DirectionCommand",
    "Drift",
    "StateChange",
    "SwarmRecord",
    "TelemetrySample",
    "Track",
    "Window",
    "analyze",
    "analyze_log",
    "check_log_file",
    "cohesion_at",
    "cohesion_series",
    "default_plot_path",
    "direction_spans",
    "drift",
    "format_summary",
    "frame_origin",
    "local_tracks",
    "mission_window",
    "plot_log",
    "read_log",
]
