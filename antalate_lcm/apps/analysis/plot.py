"""``antalate plot``: one PNG with every trajectory, every agent's state timeline and the cohesion.

matplotlib is driven through its object API on the Agg backend, never pyplot's global state, so
plotting works without a display (vehicle computers, CI) and from any thread.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

from antalate_lcm.apps.analysis.metrics import Analysis
from antalate_lcm.apps.analysis.records import SwarmRecord
from antalate_lcm.apps.analysis.swarm import SwarmSample
from antalate_lcm.apps.analysis.track import Track
from antalate_lcm.base.errors import AntalateError

#: matplotlib is an extra (90 MB with fontTools and pillow): vehicle computers and the container
#: image run nodes, not plots, so ``antalate plot`` says what to install instead of a traceback.
MATPLOTLIB_MISSING = "antalate plot needs matplotlib, which is not installed: pip install 'antalate[plot]'"

try:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch
except ImportError:
    raise AntalateError(MATPLOTLIB_MISSING) from None

#: MC state colours: calm for the ground, green for the mission, warm for the way home, red for trouble.
STATE_COLORS: dict[str, str] = {
    "INIT": "#bdbdbd",
    "STANDBY": "#9ecae1",
    "TAKEOFF": "#fdae6b",
    "MISSION": "#74c476",
    "RTL": "#9e9ac8",
    "LAND": "#c49c94",
    "MANUAL": "#ffd92f",
    "ERROR": "#de2d26",
}
#: HLC states in the same spirit (the thin bar under each agent's MC bar).
HLC_COLORS: dict[str, str] = {
    "INIT": "#bdbdbd",
    "READY": "#9ecae1",
    "TAKEOFF": "#fdd0a2",
    "GAINING_ALTITUDE": "#fdae6b",
    "AIRBORNE": "#74c476",
    "RTL": "#9e9ac8",
    "LANDING": "#c49c94",
    "MANUAL": "#ffd92f",
    "LOW_BATTERY": "#fd8d3c",
    "LLC_DOWN": "#de2d26",
}
_UNKNOWN_STATE = "#636363"


#: Phase shading on the time axes: the mission grey as before, the climb and the way home tinted.
PHASE_COLORS: dict[str, str] = {"takeoff": "#fdae6b", "mission": "black", "return": "#9e9ac8"}
#: Line styles of the trajectories by phase: the mission solid, the rest faint, so the flight home
#: (every agent to its own home point) is never read as the swarm's behaviour.
_PHASE_STYLE: dict[str, tuple[str, float, float]] = {
    "takeoff": (":", 0.8, 0.7),
    "mission": ("-", 1.0, 1.0),
    "return": ("--", 0.8, 0.6),
}


def plot(
    record: SwarmRecord,
    analysis: Analysis,
    tracks: dict[str, Track],
    out: str | Path,
    *,
    goals: Sequence[float] = (),
) -> Path:
    """Write the figure to ``out`` (PNG) and return its path; ``goals`` are radii (m) drawn on the
    cohesion panel."""
    fig = figure(record, analysis, tracks, goals=goals)
    path = Path(out)
    try:
        FigureCanvasAgg(fig).print_png(str(path))
    except OSError as exc:
        raise AntalateError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path


def figure(
    record: SwarmRecord, analysis: Analysis, tracks: dict[str, Track], *, goals: Sequence[float] = ()
) -> Figure:
    """The figure itself: trajectories (left), state timelines (top right), cohesion (bottom right);
    for a caller that adds its own panels or saves another format."""
    fig = Figure(figsize=(15, 8), dpi=100, layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=(1.05, 1.0), height_ratios=(1.0, 1.0))
    _trajectories(fig.add_subplot(grid[:, 0]), analysis, tracks)
    _timelines(fig.add_subplot(grid[0, 1]), record, analysis)
    _cohesion(fig.add_subplot(grid[1, 1]), analysis, goals)
    title = f"{Path(record.path).name}: {len(tracks)} agent(s), {record.duration:.0f} s"
    ratio = analysis.cohesion_ratio
    if ratio is not None:
        title += f"; peak radius {ratio:.2f}x the start"
    if analysis.drift and analysis.drift[0].error is not None:
        title += f"; drift error {analysis.drift[0].error:+.1f}°"
    fig.suptitle(title)
    return fig


def _trajectories(ax, analysis: Analysis, tracks: dict[str, Track]) -> None:  # type: ignore[no-untyped-def]
    cmap = _agent_colors(len(tracks))
    spans = [(p.phase.name, p.phase.start, p.phase.end) for p in analysis.phases]
    for (name, tr), color in zip(sorted(tracks.items()), cmap, strict=True):
        if not spans:
            ax.plot(tr.east, tr.north, "-", lw=0.8, color=color, label=name)
        for k, (phase, p_start, p_end) in enumerate(spans):
            idx = [i for i, t in enumerate(tr.t) if p_start <= t <= p_end]
            if not idx:
                continue
            ls, lw, alpha = _PHASE_STYLE.get(phase, ("-", 0.8, 1.0))
            ax.plot(
                [tr.east[i] for i in idx],
                [tr.north[i] for i in idx],
                ls,
                lw=0.8 * lw,
                alpha=alpha,
                color=color,
                label=name
                if phase == "mission" or (k == 0 and "mission" not in {s[0] for s in spans})
                else None,
            )
        ax.plot(tr.east[0], tr.north[0], "o", ms=5, color=color, mec="black", mew=0.5)
        ax.plot(tr.east[-1], tr.north[-1], "s", ms=4, color=color, mec="black", mew=0.5)
    w = analysis.window
    inside = [c for c in analysis.cohesion if w is None or w.start <= c.t <= w.end]
    if inside:
        ax.plot(
            [c.centroid_east for c in inside],
            [c.centroid_north for c in inside],
            "k--",
            lw=1.6,
            label="centroid (mission)",
        )
    for d in analysis.drift:
        # The commanded direction, drawn from the centroid at the span's start, as long as the drift.
        start = min(analysis.cohesion, key=lambda c: abs(c.t - d.start), default=None)
        if start is None:
            continue
        length = max(d.distance, 5.0)
        rad = math.radians(d.azimuth)
        ax.annotate(
            "",
            xy=(start.centroid_east + length * math.sin(rad), start.centroid_north + length * math.cos(rad)),
            xytext=(start.centroid_east, start.centroid_north),
            arrowprops={"arrowstyle": "->", "color": "crimson", "lw": 1.8},
        )
        ax.plot([], [], color="crimson", lw=1.8, label=f"commanded {d.azimuth:.0f}°")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.set_title("trajectories (○ start, □ end; solid: mission, dotted: takeoff, dashed: return)")
    ax.legend(fontsize=7, loc="best", ncol=2 if len(tracks) > 8 else 1)


def _timelines(ax, record: SwarmRecord, analysis: Analysis) -> None:  # type: ignore[no-untyped-def]
    names = sorted(record.agents)
    end = record.duration
    seen: set[str] = set()
    for row, name in enumerate(names):
        rec = record.agents[name]
        bars = (
            (rec.mc_states, STATE_COLORS, row + 0.05, 0.6),
            (rec.hlc_states, HLC_COLORS, row + 0.68, 0.22),
        )
        for states, colors, y, h in bars:
            for i, change in enumerate(states):
                # A state lasts until the next one, or until the agent was last heard (a silent
                # agent's bar stops where the log lost it instead of running on to the end).
                stop = states[i + 1].t if i + 1 < len(states) else min(end, rec.last_heard)
                color = colors.get(change.state, _UNKNOWN_STATE)
                if states is rec.mc_states:
                    seen.add(change.state)
                ax.broken_barh(
                    [(change.t, max(stop - change.t, 1e-3))], (y, h), facecolors=color, edgecolors="none"
                )
    _shade_phases(ax, analysis, labels=False)
    for d in record.directions:
        if not d.target:
            ax.axvline(d.t, color="crimson", lw=0.8, ls=":")
    _faults(ax, record, names)
    ax.set_yticks([i + 0.45 for i in range(len(names))], names, fontsize=7)
    ax.set_ylim(len(names), 0)
    ax.set_xlim(0, max(end, 1e-3))
    ax.set_xlabel("time since the log's start (s)")
    title = "MC state per agent (thin bar: HLC state; dotted: directions"
    ax.set_title(title + ("; black: faults)" if any(f.kind != "broadcast" for f in record.faults) else ")"))
    order = [s for s in STATE_COLORS if s in seen]
    ax.legend(
        handles=[Patch(color=STATE_COLORS[s], label=s) for s in order], fontsize=7, ncol=4, loc="lower right"
    )


def _faults(ax, record: SwarmRecord, names: list[str]) -> None:  # type: ignore[no-untyped-def]
    """An experiment's injected faults on their agents' rows: a line from start to end (to the end of
    the log for one that lasts), an X where one happens once, labelled with the kind."""
    rows = {name: i for i, name in enumerate(names)}
    starts: dict[tuple[str, str, object], float] = {}
    for f in record.faults:
        row = rows.get(f.agent)
        if row is None or f.kind == "broadcast" or f.event == "spared":
            continue
        key = (f.agent, f.kind, f.detail.get("fault"))
        if f.event == "start":
            starts[key] = f.t
            label = " ".join(
                str(x) for x in (f.kind, f.detail.get("sensor", ""), f.detail.get("vehicle", "")) if x
            )
            ax.plot([f.t], [row + 0.35], "X", color="black", ms=6, label="_fault")
            ax.annotate(label, (f.t, row + 0.35), xytext=(3, -2), textcoords="offset points", fontsize=6)
        elif f.event == "end" and key in starts:
            ax.plot([starts.pop(key), f.t], [row + 0.35, row + 0.35], "-", color="black", lw=1.5)
    for (agent, kind, _index), t in starts.items():
        lasting = {"crash", "freeze", "sensor", "byzantine", "link_loss", "packet_loss"}
        if kind in lasting:
            ax.plot([t, record.duration], [rows[agent] + 0.35] * 2, "-", color="black", lw=1.5, alpha=0.5)


def _shade_phases(ax, analysis: Analysis, *, labels: bool) -> None:  # type: ignore[no-untyped-def]
    if not analysis.phases and analysis.window is not None:  # no phases: the mission window alone
        ax.axvspan(analysis.window.start, analysis.window.end, color="black", alpha=0.06, lw=0)
    for p in analysis.phases:
        color = PHASE_COLORS.get(p.phase.name, "black")
        alpha = 0.06 if p.phase.name == "mission" else 0.12
        ax.axvspan(
            p.phase.start, p.phase.end, color=color, alpha=alpha, lw=0, label=p.phase.name if labels else None
        )


def _cohesion(ax, analysis: Analysis, goals: Sequence[float]) -> None:  # type: ignore[no-untyped-def]
    c = analysis.cohesion
    ax.plot([s.t for s in c], [s.max_distance for s in c], color="tab:red", lw=1.0, label="max (radius)")
    ax.plot([s.t for s in c], [s.mean_distance for s in c], color="tab:blue", lw=1.0, label="mean")
    extra: tuple[tuple[str, str, Callable[[SwarmSample], float | None]], ...] = (
        ("min separation", "tab:green", lambda s: s.min_separation),
        ("mean nearest neighbour", "tab:olive", lambda s: s.nn_mean),
    )
    for label, color, value in extra:
        points = [(s.t, value(s)) for s in analysis.series if value(s) is not None]
        if points:
            ax.plot([t for t, _ in points], [v for _, v in points], color=color, lw=0.8, label=label)
    _shade_phases(ax, analysis, labels=True)
    for goal in goals:
        ax.axhline(goal, color="black", lw=0.8, ls="--", label=f"goal {goal:g} m")
    ax.set_xlabel("time since the log's start (s)")
    ax.set_ylabel("distance (m)")
    ax.set_title("swarm cohesion (distance to the centroid) and separation")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="upper left")


def _agent_colors(n: int) -> list[tuple[float, float, float, float]]:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]
