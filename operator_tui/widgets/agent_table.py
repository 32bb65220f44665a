"""The agent table: one row per agent, coloured by state, like htop's process list.

Why not Textual's DataTable: with 200 flying agents nearly every row changes on every refresh, and
DataTable renders each cell through Rich's layout engine and drops its whole line cache on any
cell update; profiling showed it alone would take about a third of a core. This widget uses the
Line API instead: a row is a handful of pre-padded segments, built only for rows on screen and
cached until that row's text or style changes. The header is pinned; the cursor is the selection.

Selection leaves the table as an :class:`AgentTable.Selected` message; the table never reaches
into other widgets.
"""

from __future__ import annotations

from bisect import bisect_left
from functools import lru_cache
from typing import ClassVar

from rich.segment import Segment
from rich.style import Style
from textual import events
from textual.binding import Binding, BindingType
from textual.geometry import Region, Size
from textual.message import Message
from textual.scroll_view import ScrollView
from textual.strip import Strip

from operator_tui.board import AgentView, SwarmBoard, heading_arrow, join_limited, natural_key
from operator_tui.widgets.palette import (
    SEVERITY_STYLE,
    STALE_STYLE,
    UNKNOWN_STYLE,
    battery_style,
    hlc_style,
    mc_style,
)

#: (key, label, width). Widths are fixed so an update never re-measures 200 rows.
COLUMNS: tuple[tuple[str, str, int], ...] = (
    ("agent", "Agent", 10),
    ("mc", "MC", 7),
    ("hlc", "HLC", 11),
    ("batt", "Batt", 4),
    ("alt", "Alt m", 5),
    ("spd", "Spd", 4),
    ("hdg", "Hdg", 4),
    ("link", "Link", 4),
    ("beh", "Behaviors", 15),
    ("err", "Last error", 22),
)
#: Spaces between columns: the whole row fits a 150-column terminal beside the map.
GAP = 1
_WIDTH = {key: width for key, _, width in COLUMNS}
TABLE_WIDTH = sum(w for _, _, w in COLUMNS) + GAP * (len(COLUMNS) - 1)

#: Names longer than the HLC column, shortened in the table only (the detail view spells them out).
HLC_SHORT = {"GAINING_ALTITUDE": "GAINING_ALT"}

Cell = tuple[str, str]  # (text, style)


def format_age(age: float) -> str:
    """Link age as the table shows it: "ok" while fresh, then whole seconds, minutes, hours."""
    if age < 1.0:
        return "ok"
    if age < 100:
        return f"{age:.0f}s"
    if age < 6000:
        return f"{age / 60:.0f}m"
    return f"{age / 3600:.0f}h"


def row_cells(view: AgentView, now: float, stale_after: float) -> tuple[Cell, ...]:
    """The row of one agent as (text, style) pairs: pure, so it is tested and compared cheaply."""
    tel = view.telemetry
    age = view.link_age(now)
    if view.stale:
        link: Cell = (format_age(age), "bold red")
    elif age >= stale_after / 2:
        link = (format_age(age), "yellow")
    else:
        link = (format_age(age), "green")
    if tel is None:
        batt = alt = spd = hdg = ("", UNKNOWN_STYLE)
    else:
        batt = ("?" if tel.battery < 0 else f"{tel.battery:.0f}%", battery_style(tel.battery))
        alt = (f"{tel.alt:.1f}", "")
        spd = (f"{tel.ground_speed:.1f}", "")
        hdg = (f"{tel.heading:03.0f}{heading_arrow(tel.heading)}", "")
    failed = view.failed_behaviors
    if failed:
        beh: Cell = (join_limited(["!" + f.split(":")[0] for f in failed], _WIDTH["beh"]), "bold red")
    else:
        beh = (join_limited(view.active_behaviors, _WIDTH["beh"]), "")
    err = view.last_error
    err_cell: Cell = (
        ("", "") if err is None else (join_limited([err.text], _WIDTH["err"]), SEVERITY_STYLE[err.severity])
    )
    hlc = view.hlc_state
    cells: tuple[Cell, ...] = (
        (view.name, "bold"),
        (view.mc_state or "—", mc_style(view.mc_state)),
        (HLC_SHORT.get(hlc or "", hlc or "—"), hlc_style(hlc)),
        batt,
        alt,
        spd,
        hdg,
        link,
        beh,
        err_cell,
    )
    if view.stale:
        # Keep the last known values readable but clearly old; the link column says how old.
        cells = tuple(
            (text, f"{style} {STALE_STYLE}".strip()) if i != 7 else (text, style)
            for i, (text, style) in enumerate(cells)
        )
    return cells


@lru_cache(maxsize=256)
def _style(spec: str) -> Style:
    return Style.parse(spec) if spec else Style()


def _fit(text: str, width: int) -> str:
    return text[:width].ljust(width)


class AgentTable(ScrollView, can_focus=True):
    """Agents in natural name order; ↑/↓/PgUp/PgDn/Home/End or a click move the selection."""

    COMPONENT_CLASSES: ClassVar[set[str]] = {"agent-table--header", "agent-table--cursor", "agent-table--odd"}

    DEFAULT_CSS = """
    AgentTable {
        overflow-x: hidden;
        overflow-y: auto;
        scrollbar-size-vertical: 1;
    }
    AgentTable > .agent-table--header {
        text-style: bold;
        background: $panel;
    }
    AgentTable > .agent-table--cursor {
        background: $block-cursor-blurred-background;
    }
    AgentTable:focus > .agent-table--cursor {
        background: $block-cursor-background;
    }
    AgentTable > .agent-table--odd {
        background: $surface-lighten-1;
    }
    """

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("up", "move(-1)", "Up", show=False),
        Binding("down", "move(1)", "Down", show=False),
        Binding("pageup", "page(-1)", "Page up", show=False),
        Binding("pagedown", "page(1)", "Page down", show=False),
        Binding("home", "first", "First", show=False),
        Binding("end", "last", "Last", show=False),
    ]

    class Selected(Message):
        """The operator moved the cursor to another agent."""

        def __init__(self, agent: str | None) -> None:
            super().__init__()
            self.agent = agent

    def __init__(self, *, id: str | None = None) -> None:  # noqa: A002 - Textual's name
        super().__init__(id=id)
        self.order: list[str] = []
        self._keys: list[tuple[object, ...]] = []
        self.cells: dict[str, tuple[Cell, ...]] = {}
        self._strips: dict[str, tuple[tuple[object, ...], Strip]] = {}
        self.cursor_row = 0
        self.selected: str | None = None
        self._frame_styles: tuple[Style, Style, Style] | None = None
        # What the last sync saw, so a row scrolled into view is brought up to date when drawn.
        self._board: SwarmBoard | None = None
        self._now = 0.0
        self._tick = 0
        self._fresh: dict[str, int] = {}

    @property
    def row_count(self) -> int:
        return len(self.order)

    # ------------------------------------------------------------------ data
    def sync(self, board: SwarmBoard, now: float) -> None:
        """Bring the visible rows up to date with the board (new agents are inserted in name order).

        A virtual table: with 1,000 agents only the rows on screen are formatted each tick; a row
        scrolled into view is formatted when it is drawn (:meth:`_cells_of`)."""
        cells_of = self.cells
        new = [name for name in board.agents if name not in cells_of]
        for name in new:
            key = natural_key(name)
            i = bisect_left(self._keys, key)
            self._keys.insert(i, key)
            self.order.insert(i, name)
            cells_of[name] = ()
        changed = bool(new)
        self._board, self._now = board, now
        self._tick += 1
        fresh, tick = self._fresh, self._tick
        first = self.scroll_offset.y
        order = self.order
        for name in order[first : first + max(1, self.size.height)]:
            cells = row_cells(board.agents[name], now, board.stale_after)
            fresh[name] = tick
            if cells != cells_of[name]:
                cells_of[name] = cells
                changed = True
        if new:
            self.virtual_size = Size(TABLE_WIDTH, len(self.order) + 1)
            if self.selected in cells_of:
                self._set_cursor(self.order.index(self.selected))  # the selection follows its agent
            else:
                self._set_cursor(0)
        if changed:
            self.refresh()

    def visible_names(self) -> list[str]:
        """The agents whose rows are on screen now."""
        first = self.scroll_offset.y
        return self.order[first : first + max(1, self.size.height)]

    # ------------------------------------------------------------------ cursor
    def _set_cursor(self, row: int) -> None:
        if not self.order:
            return
        row = max(0, min(row, len(self.order) - 1))
        self.cursor_row = row
        visible = max(1, self.size.height - 1)
        top = self.scroll_offset.y
        if row < top:
            self.scroll_to(y=row, animate=False)
        elif row >= top + visible:
            self.scroll_to(y=row - visible + 1, animate=False)
        self.refresh()
        name = self.order[row]
        if name != self.selected:
            self.selected = name
            # Sent "by the table" even when sync() runs on the app's timer: Textual does not bubble
            # a message to the node that is its sender, so an app-sent message never reaches the app.
            self.post_message(self.Selected(name).set_sender(self))

    def action_move(self, delta: int) -> None:
        self._set_cursor(self.cursor_row + delta)

    def action_page(self, direction: int) -> None:
        self._set_cursor(self.cursor_row + direction * max(1, self.size.height - 2))

    def action_first(self) -> None:
        self._set_cursor(0)

    def action_last(self) -> None:
        self._set_cursor(len(self.order) - 1)

    def on_click(self, event: events.Click) -> None:
        offset = event.get_content_offset(self)
        if offset is not None and offset.y >= 1:
            self._set_cursor(self.scroll_offset.y + offset.y - 1)

    # ------------------------------------------------------------------ rendering (Line API)
    def render_line(self, y: int) -> Strip:
        width = self.size.width
        if y == 0:
            style = self.get_component_rich_style("agent-table--header")
            text = (" " * GAP).join(_fit(label, w) for _, label, w in COLUMNS)
            return Strip([Segment(_fit(text, width), style)], width)
        row = self.scroll_offset.y + y - 1
        if row >= len(self.order):
            return Strip.blank(width, self.rich_style)
        name = self.order[row]
        cells = self._cells_of(name)
        is_cursor = row == self.cursor_row
        odd = row % 2 == 1
        key = (cells, is_cursor, odd, width, self.has_focus)
        cached = self._strips.get(name)
        if cached is not None and cached[0] == key:
            return cached[1]
        base = self._row_styles()[0 if is_cursor else 1 if odd else 2]
        segments: list[Segment] = []
        gap = " " * GAP
        for i, ((_, _, w), (text, spec)) in enumerate(zip(COLUMNS, cells, strict=False)):
            segments.append(Segment(_fit(text, w), base + _style(spec)))
            if i < len(COLUMNS) - 1:
                segments.append(Segment(gap, base))
        used = TABLE_WIDTH
        if width > used:
            segments.append(Segment(" " * (width - used), base))
        strip = Strip(segments).crop(0, width)
        self._strips[name] = (key, strip)
        return strip

    def _cells_of(self, name: str) -> tuple[Cell, ...]:
        """A row's cells as of the last sync (formatted now if the row was off screen then)."""
        board = self._board
        if board is not None and self._fresh.get(name) != self._tick and name in board.agents:
            self.cells[name] = row_cells(board.agents[name], self._now, board.stale_after)
            self._fresh[name] = self._tick
        return self.cells[name]

    def _row_styles(self) -> tuple[Style, Style, Style]:
        """(cursor, odd, even) row backgrounds, resolved once per frame rather than once per row."""
        styles = self._frame_styles
        if styles is None:
            styles = self._frame_styles = (
                self.get_component_rich_style("agent-table--cursor"),
                self.get_component_rich_style("agent-table--odd"),
                self.rich_style,
            )
        return styles

    def render_lines(self, crop: Region) -> list[Strip]:
        self._frame_styles = None  # the theme or the focus may have changed since the last frame
        return super().render_lines(crop)

    def on_focus(self) -> None:
        self.refresh()

    def on_blur(self) -> None:
        self.refresh()
