"""A top-down map: every agent as an arrow pointing along its heading, coloured by MC state.

North is up. Positions are metres east/north of the first position fix heard (a fixed origin, so the
picture does not drift as agents move), and the view zooms to fit every agent. Terminal cells are
about twice as tall as wide, so one row spans two columns' worth of metres and circles look round.
Several agents in one cell show as their count; the selected agent is highlighted and labelled.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

from rich.segment import Segment
from rich.style import Style
from rich.text import Text
from textual.strip import Strip
from textual.widget import Widget

from operator_tui.board import AgentView, heading_arrow
from operator_tui.widgets.palette import STALE_STYLE, mc_style

#: Candidate scale-bar lengths (m): the map picks the longest that fits a quarter of its width.
_NICE = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 20000, 50000)
CELL_ASPECT = 2.0  # columns per row for equal metres


@dataclass(frozen=True, slots=True)
class MapPoint:
    name: str
    north: float
    east: float
    heading: float
    mc_state: str | None
    stale: bool


def fit_scale(
    points: list[MapPoint], cols: int, rows: int, min_span: float = 20.0
) -> tuple[float, float, float]:
    """(metres per column, centre north, centre east) so every point fits with a margin."""
    if points:
        north = [p.north for p in points]
        east = [p.east for p in points]
        cn, ce = (max(north) + min(north)) / 2, (max(east) + min(east)) / 2
        span_n, span_e = max(north) - min(north), max(east) - min(east)
    else:
        cn = ce = span_n = span_e = 0.0
    usable_cols = max(1, cols - 2)
    usable_rows = max(1, rows - 2)
    m_per_col = max(span_e / usable_cols, span_n / (usable_rows * CELL_ASPECT), min_span / usable_cols)
    return m_per_col * 1.1, cn, ce


Run = tuple[str, str]  # (text, style)


def map_rows(points: list[MapPoint], selected: str | None, cols: int, rows: int) -> list[list[Run]]:
    """The map as ``rows`` lines of styled runs, ``cols`` cells wide (pure: tests read its text)."""
    if cols < 8 or rows < 3:
        return []
    grid_rows = rows - 1  # the last line holds the scale bar
    m_per_col, cn, ce = fit_scale(points, cols, grid_rows)
    m_per_row = m_per_col * CELL_ASPECT
    cells: dict[tuple[int, int], list[MapPoint]] = {}
    for p in points:
        col = int(round((p.east - ce) / m_per_col + (cols - 1) / 2))
        row = int(round((cn - p.north) / m_per_row + (grid_rows - 1) / 2))
        if 0 <= col < cols and 0 <= row < grid_rows:
            cells.setdefault((row, col), []).append(p)
    grid: list[list[Run]] = [[(" ", "")] * cols for _ in range(grid_rows)]
    for (row, col), here in cells.items():
        if len(here) == 1:
            p = here[0]
            glyph = "×" if p.stale else heading_arrow(p.heading)
            style = mc_style(p.mc_state) + (f" {STALE_STYLE}" if p.stale else "")
        else:
            glyph = str(len(here)) if len(here) < 10 else "+"
            style = "bold white"
        chosen = next((p for p in here if p.name == selected), None)
        if chosen is not None:
            style = "bold reverse " + mc_style(chosen.mc_state)
        grid[row][col] = (glyph, style)
    for (row, col), here in cells.items():  # the selected agent's label, where it does not hide agents
        if any(p.name == selected for p in here) and selected:
            label = f" {selected}"
            start = col + 1 if col + 1 + len(label) <= cols else max(0, col - len(label))
            for i, ch in enumerate(label):
                if (row, start + i) not in cells:
                    grid[row][start + i] = (ch, "bold reverse")
    lines = [_merge(line) for line in grid]
    lines.append(
        _scale_bar(
            m_per_col,
            cols,
            len(points),
            selected if selected and any(p.name == selected for p in points) else None,
        )
    )
    return lines


def _merge(line: list[Run]) -> list[Run]:
    out: list[Run] = []
    for text, style in line:
        if out and out[-1][1] == style:
            out[-1] = (out[-1][0] + text, style)
        else:
            out.append((text, style))
    return out


def render_map(points: list[MapPoint], selected: str | None, cols: int, rows: int) -> Text:
    """:func:`map_rows` as one Rich Text (for tests and text captures)."""
    return Text("\n").join(Text.assemble(*line) for line in map_rows(points, selected, cols, rows))


def _scale_bar(m_per_col: float, cols: int, n: int, selected: str | None) -> list[Run]:
    """Scale, north, count, and the selected agent's name (its label may be hidden in a crowd)."""
    budget = max(2, cols // 4)
    length = next((m for m in reversed(_NICE) if m / m_per_col <= budget), _NICE[0])
    width = max(2, int(round(length / m_per_col)))
    unit = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m"
    text = "├" + "─" * (width - 2) + "┤" + f" {unit}  N↑  {n} shown"
    runs: list[Run] = [(text[:cols], "grey70")]
    if selected and len(text) + 3 < cols:
        runs.append(("  ", ""))
        runs.append((f" {selected} "[: cols - len(text) - 2], "bold reverse"))
    return runs


@lru_cache(maxsize=128)
def _style(spec: str) -> Style:
    return Style.parse(spec) if spec else Style()


class SwarmMap(Widget):
    """Draws what :meth:`update_points` gave it, aggregated per terminal cell.

    With 1,000 agents nearly every position changes on every message, but the picture (which glyph
    in which cell) changes far less: the widget compares the aggregated picture (:func:`map_rows`)
    with the one on screen and repaints only when it differs; strips are built once per change.
    """

    DEFAULT_CSS = """
    SwarmMap { height: 1fr; }
    """

    def __init__(self, *, id: str | None = None) -> None:  # noqa: A002 - Textual's name
        super().__init__(id=id)
        self.points: list[MapPoint] = []
        self.selected: str | None = None
        self._rows: list[list[Run]] = []
        self._rows_for: tuple[int, int] | None = None  # the size the picture was computed for
        self._lines: list[Strip] = []
        self._lines_for: tuple[int, int] | None = None  # the size the strips were built for
        #: How many times the picture changed (and was repainted): tests read it.
        self.repaints = 0

    def update_points(self, points: list[MapPoint], selected: str | None) -> None:
        self.points = points
        self.selected = selected
        size = (self.size.width, self.size.height)
        rows = map_rows(points, selected, *size)
        if rows != self._rows or size != self._rows_for:
            self._rows, self._rows_for, self._lines_for = rows, size, None
            self.repaints += 1
            self.refresh()

    def render_line(self, y: int) -> Strip:
        size = (self.size.width, self.size.height)
        if self._lines_for != size:
            if self._rows_for != size:  # resized since the last update
                self._rows, self._rows_for = map_rows(self.points, self.selected, *size), size
            base = self.rich_style
            self._lines = [
                Strip([Segment(text, base + _style(spec)) for text, spec in line])
                .extend_cell_length(size[0], base)
                .crop(0, size[0])
                for line in self._rows
            ]
            self._lines_for = size
        if y < len(self._lines):
            return self._lines[y]
        return Strip.blank(size[0], self.rich_style)


def points_from(positions: Iterable[tuple[AgentView, float, float]]) -> list[MapPoint]:
    """MapPoints from :meth:`SwarmBoard.positions` (kept here so the board stays UI-free)."""
    out: list[MapPoint] = []
    for view, north, east in positions:
        tel = view.telemetry
        heading = tel.heading if tel is not None and math.isfinite(tel.heading) else 0.0
        out.append(MapPoint(view.name, north, east, heading, view.mc_state, view.stale))
    out.sort(key=lambda p: p.name)
    return out
