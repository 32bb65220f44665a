"""The operator console app: wires the pure board and command tracker to the LCM node and the widgets.

One refresh timer (``settings.refresh_interval``, 4 Hz by default) drains everything the node
received, folds it into the board and the command tracker, resends what is due, and pushes the
result to the widgets. Key presses act at once (a command is on the wire before the key's handler
returns); nothing in the UI ever waits on the network. Everything mutable here is touched only
on the UI thread, so nothing needs a lock.

Keys come before bulk updates: the timer's tick decodes and folds in slices of
:data:`SLICE_ITEMS` datagrams and yields to the event loop between slices, so with 1,000 agents
(3,000 datagrams a tick) a key press waits behind one slice, not behind the whole tick.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import ClassVar

from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.css.query import NoMatches
from textual.screen import Screen
from textual.widgets import Footer

from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, NodeSettings
from antalate_lcm.wire.vocabulary import Severity
from operator_tui.board import SwarmBoard
from operator_tui.commands import CommandTracker, CommandUpdate, DirectionControl, Status, applies
from operator_tui.node import OperatorNode
from operator_tui.screens import ConfirmScreen, HelpScreen
from operator_tui.widgets.agent_table import AgentTable
from operator_tui.widgets.panels import (
    AgentDetail,
    CommandPanel,
    EventLog,
    StatusBar,
    TimeFormat,
    clock_hms,
    commands_text,
    detail_text,
    status_text,
)
from operator_tui.widgets.swarm_map import SwarmMap, points_from

log = logging.getLogger("antalate.operator")

#: Datagrams decoded and folded in between two yields to the event loop (1-2 ms of work). A key
#: press takes about seven trips through the loop from the terminal to its action, each trip
#: behind at most one slice.
SLICE_ITEMS = 100


@dataclass(frozen=True)
class ConsoleSettings:
    """Timings and steps of the console (tests shorten the timings)."""

    #: An agent not heard for this long is marked stale (state topics are republished at 5 Hz).
    stale_after: float = 3.0
    #: A pending operator command is resent this often, with the same seq.
    resend_interval: float = 1.0
    #: A command still unacknowledged after this long is marked failed.
    command_timeout: float = 10.0
    #: How often received messages are folded in and the screen refreshed. Keys act at once
    #: regardless; 4 Hz keeps 200 agents under 30 % of a core (benchmarks/tui.py), 5 Hz did not
    #: leave enough margin on a loaded machine.
    refresh_interval: float = 0.25
    #: How often the map is recomputed (it aggregates every agent, and is repainted only when its
    #: picture changed); a new agent, a new selection or a refresh_now() redraw it at once.
    map_interval: float = 1.0
    #: The latest direction command is repeated this often (directions have no ack).
    direction_repeat: float = 1.0
    azimuth_step: float = 15.0
    speed_step: float = 0.5
    initial_speed: float = 1.0
    #: Upper bound of the direction speed; None = the config's ``hlc.max_horizontal_speed``.
    max_speed: float | None = None
    #: TAKEOFF altitude sent (m); 0 = each agent's configured default.
    takeoff_altitude: float = 0.0
    #: First command seq; None = random (see operator_tui.commands). Tests fix it.
    first_seq: int | None = None
    #: How many commands the commands panel lists.
    command_rows: int = 10


G_TAKEOFF = Binding.Group("Takeoff sel/ALL")
G_LAND = Binding.Group("Land")
G_RTL = Binding.Group("RTL")
G_AZIMUTH = Binding.Group("Azimuth")
G_SPEED = Binding.Group("Speed")


class MainScreen(Screen[None]):
    """The console's single page. Command keys live here so modals shield them (see screens.py)."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("t", "app.command('TAKEOFF', False)", "Takeoff", group=G_TAKEOFF),
        Binding("T", "app.command('TAKEOFF', True)", "Takeoff all", group=G_TAKEOFF),
        Binding("l", "app.command('LAND', False)", "Land", group=G_LAND),
        Binding("L", "app.command('LAND', True)", "Land all", group=G_LAND),
        Binding("r", "app.command('RTL', False)", "RTL", group=G_RTL),
        Binding("R", "app.command('RTL', True)", "RTL all", group=G_RTL),
        Binding("a", "app.rotate(-1)", "Azimuth −15°", group=G_AZIMUTH),
        Binding("d", "app.rotate(1)", "Azimuth +15°", group=G_AZIMUTH),
        Binding("left", "app.rotate(-1)", "Azimuth −15°", show=False),
        Binding("right", "app.rotate(1)", "Azimuth +15°", show=False),
        Binding("w", "app.speed(1)", "Faster", group=G_SPEED),
        Binding("s", "app.speed(-1)", "Slower", group=G_SPEED),
        Binding("space", "app.stop_direction", "Stop dir"),
        Binding("D", "app.toggle_direction_scope", "Dir sel/ALL"),
        Binding("question_mark", "app.help", "Help"),
        Binding("q", "app.quit", "Quit"),
    ]

    def compose(self) -> ComposeResult:
        time_format = getattr(self.app, "time_format", clock_hms)
        yield StatusBar(id="status")
        with Horizontal(id="top"):
            yield AgentTable(id="agents")
            with Vertical(id="right"):
                yield SwarmMap(id="map")
                yield AgentDetail(id="detail")
        with Horizontal(id="bottom"):
            yield EventLog(id="events", time_format=time_format)
            yield CommandPanel(id="commands")
        yield Footer()

    def on_mount(self) -> None:
        self.query_one("#agents").border_title = "Agents"
        self.query_one("#map").border_title = "Map (north up)"
        self.query_one("#detail").border_title = "Detail"
        self.query_one("#events").border_title = "Events"
        self.query_one("#commands").border_title = "Commands"
        self.query_one(AgentTable).focus()
        self.call_after_refresh(self.app.refresh_now)  # type: ignore[attr-defined]


class _LogBridge(logging.Handler):
    """Routes antalate warnings logged in this process (undecodable datagrams, and the agents' own
    when the demo runs them beside the console) into the event log.

    While the console owns the terminal, a log line on stderr would scribble over the screen.
    """

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: deque[logging.LogRecord] = deque(maxlen=500)

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def _log_source(logger: str) -> str:
    """Who logged it: ``antalate.<kind>.<agent>`` names an agent (when nodes share the process)."""
    parts = logger.split(".")
    if len(parts) >= 3 and parts[1] != "operator":
        return parts[2]
    return "console"


class OperatorApp(App[None]):
    """The operator console. Give it a ``context`` to share a bus with other code (tests, the demo)."""

    CSS_PATH = "app.tcss"
    TITLE = "antalate operator"
    ENABLE_COMMAND_PALETTE = False

    def __init__(
        self,
        config: Config,
        *,
        context: Context | None = None,
        name: str = "operator",
        settings: ConsoleSettings | None = None,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
        time_format: TimeFormat = clock_hms,
        exit_after: float | None = None,
    ) -> None:
        super().__init__()
        self.settings = settings or ConsoleSettings()
        self.config = config
        self._own_context = context is None
        self.context = context if context is not None else Context.create(self.config)
        self.clock = clock
        self.wallclock = wallclock
        self.time_format = time_format
        self.exit_after = exit_after
        s = self.settings
        self.node = OperatorNode(
            NodeSettings.from_config(config, agent=name), self.context, clock=clock, wallclock=wallclock
        )
        self.board = SwarmBoard(stale_after=s.stale_after)
        self.tracker = CommandTracker(
            resend_interval=s.resend_interval, timeout=s.command_timeout, first_seq=s.first_seq
        )
        self.direction = DirectionControl(
            speed=s.initial_speed,
            azimuth_step=s.azimuth_step,
            speed_step=s.speed_step,
            max_speed=s.max_speed if s.max_speed is not None else self.config.hlc.max_horizontal_speed,
            repeat_interval=s.direction_repeat,
        )
        #: Direction keys steer every agent (True) or the selected one (False).
        self.direction_all = False
        self.selected: str | None = None
        self._log_bridge = _LogBridge()
        #: Longest stretch (s) the refresh kept the event loop (a key waits at most about this long).
        self.max_refresh = 0.0
        self._render_errors = 0
        #: Datagrams taken from the node and not folded in yet (a sliced tick may be under way).
        self._backlog: deque[tuple[str, bytes, float]] = deque()
        #: Per agent, its newest telemetry datagram not decoded yet (see _refresh_steps).
        self._deferred: dict[str, tuple[str, bytes, float]] = {}
        self._map_due = -float("inf")
        self._map_key: tuple[str | None, int] | None = None

    # ------------------------------------------------------------------ lifecycle
    def get_default_screen(self) -> Screen[None]:
        return MainScreen()

    def on_mount(self) -> None:
        logging.getLogger("antalate").addHandler(self._log_bridge)
        if self._own_context:
            self.context.executor.start()
        self.node.start()
        self.set_interval(self.settings.refresh_interval, self.refresh_sliced)
        if self.exit_after is not None:
            self.set_timer(self.exit_after, self.exit)

    def on_unmount(self) -> None:
        logging.getLogger("antalate").removeHandler(self._log_bridge)
        self.node.stop()
        if self._own_context:
            self.context.close()

    # ------------------------------------------------------------------ the refresh loop
    def refresh_now(self) -> None:
        """Fold in everything that arrived, run timeouts and resends, and redraw, all at once."""
        self._map_due = -float("inf")
        for _ in self._refresh_steps(lazy=False):
            pass

    async def refresh_sliced(self) -> None:
        """The timer's refresh: the same steps, yielding to the event loop between slices so that
        key presses (and their commands) go first."""
        for _ in self._refresh_steps(lazy=True):
            await asyncio.sleep(0)

    def _refresh_steps(self, *, lazy: bool) -> Iterator[None]:
        """One refresh, as slices of bounded work (yields between them).

        ``lazy``: the telemetry of an agent already shown once is decoded only when it is on screen
        (its table row, the detail, the map when due); until then only its arrival is noted (the
        agent is alive) and the newest datagram is kept in :attr:`_deferred`."""
        started = time.perf_counter()
        board, tracker, node = self.board, self.tracker, self.node
        backlog, deferred = self._backlog, self._deferred
        backlog.extend(node.take())
        while backlog:
            wall = self.wallclock()
            for _ in range(min(SLICE_ITEMS, len(backlog))):
                raw = backlog.popleft()
                agent = node.deferrable(raw[0])
                if agent is not None:
                    view = board.agents.get(agent)
                    if lazy and view is not None and view.telemetry is not None:
                        board.heard("TELEMETRY", agent, raw[2], wall)
                        deferred[agent] = raw
                        continue
                    deferred.pop(agent, None)  # older than this one
                item = node.decode(raw)
                if item is None:
                    continue
                try:
                    if item.unchanged:  # nothing new but that the agent is alive
                        board.heard(item.topic, item.agent, item.received, wall)
                        continue
                    board.apply(item.topic, item.agent, item.msg, item.received, wall, item.fields)
                    if item.topic == "MC_STATE":
                        for update in tracker.observe(item.agent, item.msg.last_command_seq, self.clock()):
                            self._log_update(update, wall)
                except Exception:
                    log.exception("could not show a %s message from %s", item.topic, item.agent)
            self.max_refresh = max(self.max_refresh, time.perf_counter() - started)
            yield
            started = time.perf_counter()
        now, wall = self.clock(), self.wallclock()
        if deferred:
            if not lazy or self._map_is_due(now):
                wanted = list(deferred)
            else:
                wanted = [a for a in dict.fromkeys(self._shown_agents()) if a in deferred]
            for i, agent in enumerate(wanted, 1):
                raw = deferred.pop(agent)
                item = node.decode(raw)
                if item is not None:
                    board.fold(item.topic, item.agent, item.msg, item.received, wall, item.fields)
                if i % SLICE_ITEMS == 0:
                    self.max_refresh = max(self.max_refresh, time.perf_counter() - started)
                    yield
                    started = time.perf_counter()
            now, wall = self.clock(), self.wallclock()
        while self._log_bridge.records:
            record = self._log_bridge.records.popleft()
            sev = Severity.ERROR if record.levelno >= logging.ERROR else Severity.WARNING
            board.log(wall, _log_source(record.name), record.getMessage(), sev)
        board.tick(now, wall)
        resend, updates = tracker.tick(now, board.mc_state_of, board.is_stale)
        for cmd in resend:
            self.node.send_operator_cmd(cmd.command, cmd.target, cmd.seq, altitude=cmd.altitude)
        for update in updates:
            self._log_update(update, wall)
        if self.direction.due(now) and self.direction.target is not None:
            self._publish_direction(self.direction.target, now)
        try:
            self._render(now)
        except Exception:  # a display bug must not take the operator's console down mid-flight
            self._render_errors += 1
            if self._render_errors in (1, 10, 100) or self._render_errors % 1000 == 0:
                log.exception("could not redraw the console (%d times so far)", self._render_errors)
        self.max_refresh = max(self.max_refresh, time.perf_counter() - started)

    def _map_is_due(self, now: float) -> bool:
        return now >= self._map_due or (self.selected, len(self.board.agents)) != self._map_key

    def _shown_agents(self) -> list[str]:
        """Agents whose telemetry is on screen: the table's visible rows and the selected agent."""
        screen = self._main_screen()
        shown = [self.selected] if self.selected else []
        if screen is not None and screen.is_mounted:
            with contextlib.suppress(NoMatches):
                shown.extend(screen.query_one(AgentTable).visible_names())
        return shown

    def _render(self, now: float) -> None:
        screen = self._main_screen()
        if screen is None or not screen.is_mounted:
            return
        try:
            self._render_on(screen, now)
        except NoMatches:  # the screen is being torn down (the app is exiting)
            return

    def _render_on(self, screen: MainScreen, now: float) -> None:
        board = self.board
        screen.query_one(AgentTable).sync(board, now)
        if self._map_is_due(now):
            # Fixed-rate: every agent's position is aggregated into the picture once a map_interval.
            self._map_due = now + self.settings.map_interval
            self._map_key = (self.selected, len(board.agents))
            screen.query_one(SwarmMap).update_points(points_from(board.positions()), self.selected)
        screen.query_one(AgentDetail).show(
            detail_text(board.agents.get(self.selected or ""), now, self.time_format)
        )
        screen.query_one(CommandPanel).show(
            commands_text(self.tracker.recent(self.settings.command_rows), now, self.board.mc_state_of)
        )
        screen.query_one(EventLog).add(board.take_events())
        counts = self.tracker.counts()
        screen.query_one(StatusBar).show(
            status_text(
                bus=self.node.bus_summary(),
                agents=len(board.agents),
                stale=board.stale_count,
                pending=counts[Status.PENDING],
                failed=counts[Status.FAILED],
                direction=self.direction,
                scope_all=self.direction_all,
                selected=self.selected,
                safety=board.safety_summary(now),
            )
        )

    def _main_screen(self) -> MainScreen | None:
        for screen in self.screen_stack:
            if isinstance(screen, MainScreen):
                return screen
        return None

    def _log_update(self, update: CommandUpdate, wall: float) -> None:
        self.board.log(
            wall,
            update.command.target or "ALL",
            update.text,
            Severity.ERROR if update.failed else Severity.INFO,
        )

    # ------------------------------------------------------------------ widget messages
    def on_agent_table_selected(self, message: AgentTable.Selected) -> None:
        self.selected = message.agent
        self._render(self.clock())

    # ------------------------------------------------------------------ actions (keys)
    def action_command(self, command: str, to_all: bool) -> None:
        if to_all:
            live = self.board.live_names()
            detail = (
                f"Broadcast on SWARM/OPERATOR_CMD; waiting for {len(live)} live agent(s) to acknowledge."
                if live
                else "No live agent is known: it will be broadcast anyway."
            )

            def answered(yes: bool | None) -> None:
                if yes:
                    self.send_command(command, "")

            self.push_screen(ConfirmScreen(f"Send {command} to ALL agents?", detail), answered)
            return
        if self.selected is None:
            self.notify("No agent selected.", severity="warning")
            return
        self.send_command(command, self.selected)

    def send_command(self, command: str, target: str) -> None:
        """Send a new operator command now ("" = all agents) and track it until acknowledged."""
        now, wall = self.clock(), self.wallclock()
        expected = self.board.live_names() if not target else [target]
        altitude = self.settings.takeoff_altitude if command == "TAKEOFF" else 0.0
        cmd = self.tracker.new(command, target, now, expected=expected, altitude=altitude)
        channel = self.node.send_operator_cmd(command, target, cmd.seq, altitude=altitude)
        text = f"sent {cmd.label} #{cmd.seq} on {channel}"
        severity = Severity.INFO
        state = self.board.mc_state_of(target) if target else None
        if applies(command, state) is False:
            text += f" — MC is {state}: it will likely be rejected"
            severity = Severity.WARNING
        self.board.log(wall, target or "ALL", text, severity)
        self._render(now)

    def action_rotate(self, steps: int) -> None:
        self.direction.rotate(steps)
        self._send_direction()

    def action_speed(self, steps: int) -> None:
        self.direction.change_speed(steps)
        self._send_direction()

    def action_stop_direction(self) -> None:
        self.direction.stop()
        self._send_direction()

    def _send_direction(self) -> None:
        target = "" if self.direction_all else self.selected
        if target is None:
            self.notify("No agent selected (D steers ALL agents).", severity="warning")
            return
        now = self.clock()
        self._publish_direction(target, now)
        d = self.direction
        state = f"{d.azimuth:03.0f}° {d.speed:.1f} m/s" if d.active else "stop"
        self.board.log(self.wallclock(), target or "ALL", f"direction {state}")
        self._render(now)

    def _publish_direction(self, target: str, now: float) -> None:
        d = self.direction
        self.node.send_direction(active=d.active, azimuth=d.azimuth, speed=d.speed, target=target)
        d.sent(target, now)

    def action_toggle_direction_scope(self) -> None:
        if self.direction_all:
            self.direction_all = False
            self._render(self.clock())
            return

        def answered(yes: bool | None) -> None:
            if yes:
                self.direction_all = True
                self._render(self.clock())

        self.push_screen(
            ConfirmScreen(
                "Steer ALL agents with the direction keys?", "Directions will go to SWARM/DIRECTION_CMD."
            ),
            answered,
        )

    def action_help(self) -> None:
        self.push_screen(HelpScreen())
