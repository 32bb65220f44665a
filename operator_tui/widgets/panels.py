"""The text panels: status bar, agent detail, commands and event log.

Each is fed by the app (``show(...)``) and formats pure data; the ``*_text`` functions are pure so the
formats are tested without a terminal. A panel only repaints when its text actually changed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from rich.text import Text
from textual.geometry import Region
from textual.widgets import RichLog, Static

from antalate_lcm.wire.vocabulary import Severity
from operator_tui.board import AgentView, Event, SafetySummary, heading_arrow
from operator_tui.commands import DirectionControl, Status, TrackedCommand, applies
from operator_tui.widgets.palette import SEVERITY_STYLE, battery_style, hlc_style, mc_style

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self is 3.11+

TimeFormat = Callable[[float], str]


def clock_hms(wall: float) -> str:
    """Local wall-clock time of an event, as operators read their watches."""
    return time.strftime("%H:%M:%S", time.localtime(wall))


def _age(seconds: float) -> str:
    return f"{seconds:.1f}s" if seconds < 100 else f"{seconds / 60:.0f}m"


def _link_age(seconds: float) -> str:
    """Per-topic link age in the detail view: "ok" while fresh, so the panel is not redrawn for nothing."""
    return "ok" if seconds < 1.0 else _age(seconds)


# ---------------------------------------------------------------------- status bar
def status_text(
    *,
    bus: str,
    agents: int,
    stale: int,
    pending: int,
    failed: int,
    direction: DirectionControl,
    scope_all: bool,
    selected: str | None,
    safety: SafetySummary | None = None,
) -> Text:
    t = Text()
    t.append(" antalate operator ", "bold reverse")
    t.append(f"  {bus}  ", "grey70")
    t.append(f"agents {agents}", "bold")
    if stale:
        t.append(f" ({stale} stale)", "bold red")
    t.append("  cmds ")
    t.append(f"{pending} pending", "yellow" if pending else "grey62")
    if failed:
        t.append(f" {failed} failed", "bold red")
    t.append("  dir→")
    t.append("ALL" if scope_all else (selected or "(none)"), "bold magenta" if scope_all else "bold")
    t.append(f" {direction.azimuth:03.0f}°{heading_arrow(direction.azimuth)} {direction.speed:.1f} m/s ")
    t.append("ON" if direction.active else "off", "bold green" if direction.active else "grey62")
    if safety is not None:
        t.append("  safety ")
        if safety.modified:
            shown = ", ".join(f"{n} by {by}" for by, n in sorted(safety.modified.items()))
            t.append(f"modifying {shown}", "bold yellow")
        else:
            t.append("idle", "grey62")
        if safety.closest is not None:
            d, a, b = safety.closest
            t.append(f"  closest {a}-{b} {d:.1f} m")
    return t


class _TextPanel(Static):
    """A fixed-size panel showing one `Text`, redrawn only when the text changes and never re-laying
    out the screen (the console refreshes its panels several times a second)."""

    def show(self, text: Text) -> None:
        if text != getattr(self, "_last", None):
            self._last = text
            self.update(text, layout=False)


class StatusBar(_TextPanel):
    """The line across the top: bus, agents, commands, the direction control, the safety filter."""


# ---------------------------------------------------------------------- detail
_TOPIC_SHORT = {
    "MC_STATE": "MC",
    "HLC_STATE": "HLC",
    "TELEMETRY": "TEL",
    "HLC_ERROR": "ERR",
    "ARBITER": "BMA",
}


def detail_text(view: AgentView | None, now: float, time_format: TimeFormat = clock_hms) -> Text:
    """Everything about one agent: the table's row spelled out, per-topic link ages, arbiters."""
    if view is None:
        return Text("No agent selected.\nAgents appear here as soon as their channels are heard.", "grey62")
    t = Text()
    t.append(view.name, "bold")
    if view.stale:
        t.append("  STALE", "bold red")
    t.append("\nMC  ")
    t.append(view.mc_state or "—", mc_style(view.mc_state))
    t.append("   HLC ")
    t.append(view.hlc_state or "—", hlc_style(view.hlc_state))
    if view.autopilot:
        t.append(f"   ({view.autopilot})", "grey62")
    for who, why in (("MC", view.mc_reason), ("HLC", view.hlc_reason)):
        if why:  # why it is in that state (a failsafe, the link-regained policy, ...)
            t.append(f"\n{who}: {why}", "grey62")
    tel = view.telemetry
    if tel is None:
        t.append("\nno telemetry yet", "grey62")
    else:
        t.append(f"\npos {tel.lat:.6f}, {tel.lon:.6f}  alt {tel.alt:.1f} m")
        t.append(
            f"\nhdg {tel.heading:03.0f}°{heading_arrow(tel.heading)}  gs {tel.ground_speed:.1f} m/s  vd {tel.vd:+.1f}"
        )
        t.append("\nbatt ")
        t.append("?" if tel.battery < 0 else f"{tel.battery:.0f}%", battery_style(tel.battery))
        t.append(f"  {'armed' if tel.armed else 'disarmed'}  {'in air' if tel.in_air else 'on ground'}")
        t.append(f"\nmode {tel.mode or '—'}")
    heard = "  ".join(
        f"{_TOPIC_SHORT.get(topic, topic)} {_link_age(now - at)}" for topic, at in sorted(view.heard.items())
    )
    t.append(f"\nlink {heard}", "bold red" if view.stale else "")
    t.append(
        f"\nmsgs {view.messages}  ack seq {view.last_command_seq if view.last_command_seq is not None else '—'}"
    )
    for name, arb in sorted(view.arbiters.items()):
        t.append(f"\nBMA {name or '?'} [{arb.state}]: ")
        t.append(", ".join(arb.active) or "(none active)", "green" if arb.active else "grey62")
        for fail in arb.failed:
            t.append(f"\n  failed {fail}", "bold red")
    safety = view.last_safety
    if safety is not None and safety is not view.last_error:
        t.append("\nsafety ")
        t.append(f"{time_format(safety.wall)} {safety.text}", SEVERITY_STYLE[safety.severity])
    err = view.last_error
    if err is not None:
        t.append("\nerr ")
        t.append(
            f"{time_format(err.wall)} [{err.severity.name} {err.code}] {err.text}",
            SEVERITY_STYLE[err.severity],
        )
        if view.errors > 1:
            t.append(f" ({view.errors} total)", "grey62")
    return t


class AgentDetail(_TextPanel):
    """The selected agent's states, telemetry, behaviors and last error."""


# ---------------------------------------------------------------------- commands
_STATUS_STYLE = {Status.PENDING: "bold yellow", Status.ACKED: "green", Status.FAILED: "bold red"}


def command_line(
    cmd: TrackedCommand, now: float, mc_state_of: Callable[[str], str | None] = lambda _a: None
) -> Text:
    t = Text()
    t.append(f"#{cmd.seq} ", "grey62")
    t.append(f"{cmd.label:<18} ")
    if cmd.status is Status.PENDING:
        t.append(f"pending {_age(cmd.age(now))}", _STATUS_STYLE[cmd.status])
        if cmd.sends > 1:
            t.append(f" ×{cmd.sends}", "yellow")
        if cmd.broadcast and cmd.expected:
            t.append(f" {cmd.progress}", "yellow")
        if cmd.target and applies(cmd.command, mc_state_of(cmd.target)) is False:
            t.append(f" (MC {mc_state_of(cmd.target)}: rejected?)", "bold red")
    elif cmd.status is Status.ACKED:
        t.append(f"acked {_age(cmd.age(now))}" if not cmd.reason else cmd.reason, _STATUS_STYLE[cmd.status])
    else:
        t.append("FAILED ", _STATUS_STYLE[cmd.status])
        t.append(cmd.reason, "red")
    return t


def commands_text(
    cmds: Iterable[TrackedCommand], now: float, mc_state_of: Callable[[str], str | None] = lambda _a: None
) -> Text:
    lines = [command_line(c, now, mc_state_of) for c in reversed(list(cmds))]
    if not lines:
        return Text("No commands sent yet.\nt/l/r: selected agent, T/L/R: all agents.", "grey62")
    return Text("\n").join(lines)


class CommandPanel(Static):
    def show(self, text: Text) -> None:
        if text != getattr(self, "_last", None):
            self._last = text
            self.update(text, layout=False)  # fixed-size panels: no re-layout of the screen


# ---------------------------------------------------------------------- events
def event_line(ev: Event, time_format: TimeFormat = clock_hms) -> Text:
    t = Text()
    t.append(time_format(ev.wall), "grey62")
    t.append(" ")
    t.append(f"{ev.agent or '*':<10}", "bold")
    t.append(" ")
    t.append(ev.text, SEVERITY_STYLE[ev.severity] if ev.severity is not Severity.INFO else "")
    return t


class EventLog(RichLog):
    """The event log: newest at the bottom, scrolls on its own unless the operator scrolled up.

    Appending lines changes the log's virtual size, for which Textual lays out and repaints the
    whole screen (the 1,000-row table and the map too: tens of milliseconds, and every tick brings
    events with a large swarm). The log's own size is fixed by the layout, so while lines are
    appended a layout is skipped unless a scrollbar appears or disappears; the scrollbars are
    updated in place and only the log is repainted.
    """

    def __init__(self, *, time_format: TimeFormat = clock_hms, id: str | None = None) -> None:  # noqa: A002
        super().__init__(id=id, max_lines=2000, wrap=True, markup=False, highlight=False, auto_scroll=True)
        self.time_format = time_format
        self._appending = False
        #: Layouts skipped while appending (tests read it).
        self.layouts_skipped = 0

    def add(self, events: Iterable[Event]) -> None:
        self._appending = True
        wrote = False
        try:
            for ev in events:
                self.write(event_line(ev, self.time_format), scroll_end=False)
                wrote = True
        finally:
            self._appending = False
        if wrote and self.auto_scroll:  # once per batch, not once per line
            self.scroll_end(animate=False, immediate=False, x_axis=False)

    def refresh(
        self, *regions: Region, repaint: bool = True, layout: bool = False, recompose: bool = False
    ) -> Self:
        if layout and self._appending and not recompose and self.is_mounted:
            shown = (self.show_horizontal_scrollbar, self.show_vertical_scrollbar)
            self._scroll_update(self.virtual_size)  # recomputes which scrollbars show
            if (self.show_horizontal_scrollbar, self.show_vertical_scrollbar) == shown:
                layout = False
                self.layouts_skipped += 1
        return super().refresh(*regions, repaint=repaint, layout=layout, recompose=recompose)
