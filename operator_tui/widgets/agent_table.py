"""The agent table: one row per agent, coloured by state, like htop's process list.

Rows are recomputed from the model on every refresh, but a cell is only pushed to the DataTable
when its text or style changed, and columns have fixed widths (no re-measuring), so 200 agents
cost a few hundred string comparisons per refresh. Selection leaves the table as an
:class:`AgentTable.Selected` message; the table never reaches into other widgets.
"""

from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual.binding import Binding, BindingType
from textual.coordinate import Coordinate
from textual.message import Message
from textual.widgets import DataTable
from textual.widgets.data_table import CellDoesNotExist

from operator_tui.model import AgentView, SwarmModel, heading_arrow, join_limited, natural_key
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
#: One space between columns instead of DataTable's two (cell_padding=0, width + 1): the whole
#: row fits a 150-column terminal beside the map.
GAP = 1
_WIDTH = {key: width for key, _, width in COLUMNS}

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
    active = join_limited(view.active_behaviors, _WIDTH["beh"])
    failed = view.failed_behaviors
    beh: Cell = (join_limited(["!" + f.split(":")[0] for f in failed], _WIDTH["beh"]), "bold red") if failed else (active, "")
    err = view.last_error
    err_cell: Cell = ("", "") if err is None else (join_limited([err.text], _WIDTH["err"]), SEVERITY_STYLE[err.severity])
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
        cells = tuple((text, f"{style} {STALE_STYLE}".strip()) if i != 7 else (text, style) for i, (text, style) in enumerate(cells))
    return cells


class AgentTable(DataTable[Text], inherit_bindings=False):
    """DataTable of agents. Left/right are left to the screen (they steer the direction)."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("up", "cursor_up", "Up", show=False),
        Binding("down", "cursor_down", "Down", show=False),
        Binding("pageup", "page_up", "Page up", show=False),
        Binding("pagedown", "page_down", "Page down", show=False),
        Binding("home", "scroll_top", "First", show=False),
        Binding("end", "scroll_bottom", "Last", show=False),
    ]

    class Selected(Message):
        """The operator moved the cursor to another agent."""

        def __init__(self, agent: str | None) -> None:
            super().__init__()
            self.agent = agent

    def __init__(self, *, id: str | None = None) -> None:  # noqa: A002 - Textual's name
        super().__init__(id=id, cursor_type="row", zebra_stripes=True, cell_padding=0)
        self._shown: dict[str, tuple[Cell, ...]] = {}
        self.selected: str | None = None

    def on_mount(self) -> None:
        for i, (key, label, width) in enumerate(COLUMNS):
            self.add_column(label, width=width + (GAP if i < len(COLUMNS) - 1 else 0), key=key)

    def sync(self, model: SwarmModel, now: float) -> None:
        """Bring every row up to date with the model (new agents are inserted in name order)."""
        new = [name for name in model.agents if name not in self._shown]
        for name in new:
            cells = row_cells(model.agents[name], now, model.stale_after)
            self._shown[name] = cells
            self.add_row(*(Text(t, style=s) for t, s in cells), key=name)
        if new:
            self.sort("agent", key=lambda cell: natural_key(cell.plain))
            if self.selected in self._shown:
                self.move_cursor(row=self.get_row_index(self.selected))
            elif self.row_count:
                self.move_cursor(row=0)
                self._select_row(0)
        for name, view in model.agents.items():
            cells = row_cells(view, now, model.stale_after)
            shown = self._shown[name]
            if cells == shown:
                continue
            for (key, _, _), cell, old in zip(COLUMNS, cells, shown, strict=True):
                if cell != old:
                    self.update_cell(name, key, Text(cell[0], style=cell[1]))
            self._shown[name] = cells

    def select_agent(self, name: str) -> None:
        if name in self._shown:
            self.move_cursor(row=self.get_row_index(name))

    def _select_row(self, index: int) -> None:
        try:
            key = self.coordinate_to_cell_key(Coordinate(index, 0)).row_key.value
        except CellDoesNotExist:  # an empty table
            key = None
        if key != self.selected:
            self._announce(key)

    def _announce(self, key: str | None) -> None:
        self.selected = key
        # Sent "by the table" even when sync() runs on the app's timer: Textual does not bubble a
        # message to the node that is its sender, so an app-sent message would never reach the app.
        self.post_message(self.Selected(key).set_sender(self))

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        event.stop()
        # The cursor, not the event, is the truth: an event queued before a re-sort names the
        # row that *was* under the cursor.
        self._select_row(self.cursor_row)
