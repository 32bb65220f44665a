"""The operator console driven by Textual's pilot, on a memq:// bus shared with fake agents.

The app and the fake agents use the same :class:`Context` (memq is per LCM instance, and the Bus
keeps one instance per URL), so what a test publishes reaches the console through the real node,
executor and drain path, and what a key sends is captured as decoded messages. Time is a fake
clock: staleness, resends and timeouts advance only when a test says so, and no test sleeps for them.
"""

from __future__ import annotations

import asyncio
import dataclasses
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator
from typing import Any, TypeVar

import pytest

from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context
from antalate_lcm.msgs import (
    arbiter_status_t,
    direction_cmd_t,
    hlc_error_t,
    hlc_state_t,
    mc_state_t,
    operator_cmd_t,
    telemetry_t,
)
from antalate_lcm.wire.security import sign, verify
from antalate_lcm.wire.vocabulary import Command, name_of
from operator_tui.app import SLICE_ITEMS, ConsoleSettings, OperatorApp
from operator_tui.board import EventKind, Telemetry
from operator_tui.commands import Status
from operator_tui.screens import ConfirmScreen, HelpScreen
from operator_tui.widgets.agent_table import COLUMNS, AgentTable
from operator_tui.widgets.panels import EventLog
from operator_tui.widgets.swarm_map import SwarmMap, points_from
from tests.harness.clock import FakeClock
from tests.harness.netns import NetNamespace, run_unrouted

T = TypeVar("T")

FIRST_SEQ = 1000
WALL0 = 1_800_000_000.0


class FakeSwarm:
    """Publishes what agents publish and records what the console sends, on the shared bus."""

    def __init__(self, bus: Buses, bus_name: str = "lan") -> None:
        self.bus = bus
        self.bus_name = bus_name
        self.commands: list[tuple[str, operator_cmd_t]] = []
        self.directions: list[tuple[str, direction_cmd_t]] = []
        #: The swarm key the agents sign with (None: they do not sign), and the console's fake clock
        #: their messages are stamped by when they sign (a signed message is checked for its age).
        self.key: str | None = None
        self.clock: FakeClock | None = None
        self._lock = threading.Lock()
        bus.subscribe(bus_name, r".*OPERATOR_CMD", operator_cmd_t, self._on_cmd, regex=True)
        bus.subscribe(bus_name, r".*DIRECTION_CMD", direction_cmd_t, self._on_dir, regex=True)

    def _on_cmd(self, channel: str, msg: operator_cmd_t) -> None:
        with self._lock:
            self.commands.append((channel, msg))

    def _on_dir(self, channel: str, msg: direction_cmd_t) -> None:
        with self._lock:
            self.directions.append((channel, msg))

    def _pub(self, channel: str, msg: Any, agent: str) -> None:
        msg.header.agent = agent
        msg.header.utime = int((WALL0 + (self.clock() if self.clock is not None else 0.0)) * 1e6)
        if self.key is not None:
            sign(msg, self.key)
        self.bus.publish(self.bus_name, channel, msg)

    def mc(self, agent: str, state: int = mc_state_t.STANDBY, last: int = 0) -> None:
        m = mc_state_t()
        m.state, m.last_command_seq = state, last
        self._pub(f"{agent}/MC_STATE", m, agent)

    def hlc(self, agent: str, state: int = hlc_state_t.READY) -> None:
        m = hlc_state_t()
        m.state, m.autopilot = state, "sim"
        self._pub(f"{agent}/HLC_STATE", m, agent)

    def tel(
        self,
        agent: str,
        *,
        lat: float = 47.3977,
        lon: float = 8.5456,
        alt: float = 0.0,
        heading: float = 0.0,
        vn: float = 0.0,
        ve: float = 0.0,
        battery: float = 100.0,
        in_air: bool = False,
    ) -> None:
        m = telemetry_t()
        m.lat, m.lon, m.alt, m.heading, m.vn, m.ve, m.battery = lat, lon, alt, heading, vn, ve, battery
        m.armed = m.in_air = in_air
        m.mode = "SIM"
        self._pub(f"{agent}/TELEMETRY", m, agent)

    def error(self, agent: str, text: str, code: int = 7, severity: int = hlc_error_t.ERROR) -> None:
        m = hlc_error_t()
        m.code, m.severity, m.text = code, severity, text
        self._pub(f"{agent}/HLC_ERROR", m, agent)

    def arbiter(self, agent: str, name: str, state: str, active: list[str]) -> None:
        m = arbiter_status_t()
        m.arbiter, m.state, m.n, m.active = name, state, len(active), active
        self._pub(f"{agent}/ARBITER/{name}", m, agent)

    def agent(
        self, name: str, mc: int = mc_state_t.STANDBY, hlc: int = hlc_state_t.READY, last: int = 0, **tel: Any
    ) -> None:
        self.mc(name, mc, last)
        self.hlc(name, hlc)
        self.tel(name, **tel)

    def flying(self, name: str, **tel: Any) -> None:
        """An agent in its mission, airborne, with this telemetry."""
        self.agent(name, mc_state_t.MISSION, hlc_state_t.AIRBORNE, in_air=True, **tel)

    def sent(self) -> list[tuple[str, operator_cmd_t]]:
        with self._lock:
            return list(self.commands)

    def sent_directions(self) -> list[tuple[str, direction_cmd_t]]:
        with self._lock:
            return list(self.directions)


def memq_config(**extra: Any) -> Config:
    return parse_config({"buses": {"lan": "memq://"}, "agent": {"name": "unused"}, **extra})


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context(Buses({"lan": "memq://"}), Executor())
    ctx.executor.start()
    yield ctx
    ctx.close()


@pytest.fixture
def swarm(context: Context) -> FakeSwarm:
    return FakeSwarm(context.buses)


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock(100.0)  # shared by the app and the node


def utc_hms(wall: float) -> str:
    return time.strftime("%H:%M:%S", time.gmtime(wall))


def make_app(
    context: Context, clock: FakeClock, config: Config | None = None, **settings: Any
) -> OperatorApp:
    base = {"first_seq": FIRST_SEQ, "stale_after": 3.0, "resend_interval": 1.0, "command_timeout": 5.0}
    wall = lambda: WALL0 + clock()  # noqa: E731 - the wall clock moves with the fake clock
    return OperatorApp(
        config or memq_config(),
        context=context,
        settings=ConsoleSettings(**{**base, **settings}),
        clock=clock,
        wallclock=wall,
        time_format=utc_hms,
    )


async def until(pilot: Any, app: OperatorApp, cond: Callable[[], T], timeout: float = 10.0) -> T:
    """Refresh the app until ``cond()`` holds (messages cross two threads before the UI sees them)."""
    deadline = time.monotonic() + timeout
    while True:
        app.refresh_now()
        value = cond()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"condition not met within {timeout} s")
        await pilot.pause(0.02)


def telemetry(app: OperatorApp, name: str) -> Telemetry:
    """The agent's last decoded telemetry (it must have one by then)."""
    tel = app.board.agents[name].telemetry
    assert tel is not None, f"{name} has no telemetry yet"
    return tel


async def wait_count(pilot: Any, app: OperatorApp, read: Callable[[], list[T]], n: int) -> list[T]:
    """What ``read()`` returns once it holds ``n`` items or more."""

    def enough() -> list[T] | None:
        items = read()
        return items if len(items) >= n else None

    items = await until(pilot, app, enough)
    assert items is not None
    return items


async def wait_sent(
    pilot: Any, app: OperatorApp, swarm: FakeSwarm, n: int
) -> list[tuple[str, operator_cmd_t]]:
    return await wait_count(pilot, app, swarm.sent, n)


async def wait_dirs(
    pilot: Any, app: OperatorApp, swarm: FakeSwarm, n: int
) -> list[tuple[str, direction_cmd_t]]:
    return await wait_count(pilot, app, swarm.sent_directions, n)


async def settle(pilot: Any) -> None:
    """Let bus threads deliver anything in flight (used before asserting that nothing was sent)."""
    await asyncio.sleep(0.15)
    await pilot.pause()


@pytest.fixture
async def two_agents(
    context: Context, swarm: FakeSwarm, clock: FakeClock
) -> AsyncIterator[tuple[OperatorApp, Any]]:
    app = make_app(context, clock)
    async with app.run_test(size=(160, 44)) as pilot:
        swarm.agent("alpha", lat=47.3977, lon=8.5456)
        swarm.flying("bravo", lat=47.3980, lon=8.5460, alt=12.5, heading=90.0, ve=2.0, battery=35.0)
        await until(pilot, app, lambda: len(app.board.agents) == 2 and app.selected == "alpha")
        yield app, pilot


def table_row(app: OperatorApp, agent: str) -> dict[str, str]:
    table = app.screen.query_one(AgentTable)
    return {key: text for (key, _, _), (text, _) in zip(COLUMNS, table.cells[agent], strict=True)}


# ---------------------------------------------------------------------- discovery and display
async def test_agent_messages_appear_as_rows(context: Context, swarm: FakeSwarm, clock: FakeClock) -> None:
    app = make_app(context, clock)
    async with app.run_test(size=(160, 44)) as pilot:
        table = app.screen.query_one(AgentTable)
        assert table.row_count == 0
        swarm.flying("uav10", alt=12.34, heading=271.0, vn=3.0, ve=4.0, battery=55.0)
        swarm.agent("uav2")
        swarm.arbiter("uav10", "main", "MISSION", ["dovrat_swarm", "video_capture"])
        swarm.error("uav10", "arming refused: battery low", code=12)
        await until(
            pilot, app, lambda: table.row_count == 2 and app.board.agents["uav10"].last_error is not None
        )
        await pilot.pause()
        assert table.order == ["uav2", "uav10"]
        assert table_row(app, "uav10") == {
            "agent": "uav10",
            "mc": "MISSION",
            "hlc": "AIRBORNE",
            "batt": "55%",
            "alt": "12.3",
            "spd": "5.0",
            "hdg": "271←",
            "link": "ok",
            "beh": "dovrat_swarm, …",
            "err": "arming refused: batte…",
        }
        assert table.cells["uav10"][1] == ("MISSION", "bold green")  # coloured by state
        assert table.cells["uav2"][1] == ("STANDBY", "cyan")
        # The selection is the agent under the cursor; the detail follows it; the map shows both.
        assert app.selected == table.order[table.cursor_row]
        assert len(app.screen.query_one("#map").points) == 2  # type: ignore[attr-defined]
        await pilot.press("end")
        await until(pilot, app, lambda: app.selected == "uav10")
        assert "dovrat_swarm" in str(app.screen.query_one("#detail").render())
        await pilot.press("home")
        await until(pilot, app, lambda: app.selected == "uav2")
        assert "uav2" in str(app.screen.query_one("#detail").render())
        # A new agent sorted in before the selection does not move the selection to another agent.
        swarm.mc("uav1")
        await until(pilot, app, lambda: table.row_count == 3)
        await pilot.pause()
        assert app.selected == "uav2" and table.cursor_row == 1


async def test_silent_agents_are_marked_stale_not_removed(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm, clock: FakeClock
) -> None:
    app, pilot = two_agents
    clock.advance(2.0)
    swarm.mc("bravo", mc_state_t.MISSION)
    await until(pilot, app, lambda: app.board.agents["bravo"].link_age(clock()) == 0.0)
    clock.advance(1.5)  # alpha silent 3.5 s > 3 s; bravo 1.5 s
    app.refresh_now()
    assert app.board.agents["alpha"].stale and not app.board.agents["bravo"].stale
    table = app.screen.query_one(AgentTable)
    assert table.row_count == 2
    row = table.cells["alpha"]
    assert row[7] == ("4s", "bold red")
    assert "dim" in row[1][1]
    assert table_row(app, "bravo")["link"] == "2s"
    assert any(e.kind.value == "stale" and e.agent == "alpha" for e in app.board.events)
    swarm.mc("alpha")
    await until(pilot, app, lambda: not app.board.agents["alpha"].stale)
    assert table_row(app, "alpha")["link"] == "ok"


# ---------------------------------------------------------------------- commands
async def test_each_key_sends_the_right_command_to_the_right_channel(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm
) -> None:
    app, pilot = two_agents
    await pilot.press("down")
    await until(pilot, app, lambda: app.selected == "bravo")
    expected = []
    for key, command in (("t", "TAKEOFF"), ("l", "LAND"), ("r", "RTL")):
        await pilot.press(key)
        expected.append(("bravo/OPERATOR_CMD", command, "bravo"))
    for key, command in (("T", "TAKEOFF"), ("L", "LAND"), ("R", "RTL")):
        await pilot.press(key)
        assert isinstance(app.screen, ConfirmScreen)
        await pilot.press("y")
        expected.append(("SWARM/OPERATOR_CMD", command, ""))
    sent = await wait_sent(pilot, app, swarm, 6)
    assert [(ch, name_of(Command, m.command), m.target) for ch, m in sent] == expected
    assert [m.header.seq for _, m in sent] == list(range(FIRST_SEQ, FIRST_SEQ + 6))
    assert {m.header.agent for _, m in sent} == {"operator"}
    assert all(m.header.mac_len == 0 for _, m in sent)  # no swarm key configured
    assert len(app.tracker.pending) == 6


async def test_all_agent_commands_are_not_sent_without_confirmation(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm
) -> None:
    app, pilot = two_agents
    await pilot.press("T")
    assert isinstance(app.screen, ConfirmScreen)
    await pilot.press("t")  # command keys do nothing while the modal is open
    await pilot.press("n")
    assert not isinstance(app.screen, ConfirmScreen)
    await pilot.press("L")
    await pilot.press("escape")
    await pilot.press("R")
    await pilot.press("enter")  # focus starts on "No"
    await settle(pilot)
    assert swarm.sent() == [] and not app.tracker.pending


async def test_ack_through_last_command_seq_clears_pending(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm, clock: FakeClock
) -> None:
    app, pilot = two_agents
    await pilot.press("t")
    ((_, msg),) = await wait_sent(pilot, app, swarm, 1)
    cmd = app.tracker.pending[msg.header.seq]
    assert "pending" in str(app.screen.query_one("#commands").render())
    swarm.mc("alpha", mc_state_t.STANDBY, last=FIRST_SEQ + 77)  # someone else's command: not ours
    clock.advance(0.3)
    await settle(pilot)
    app.refresh_now()
    assert cmd.status is Status.PENDING
    swarm.mc("alpha", mc_state_t.TAKEOFF, last=msg.header.seq)
    await until(pilot, app, lambda: cmd.status is Status.ACKED)
    assert not app.tracker.pending
    assert "acked 0.3s" in str(app.screen.query_one("#commands").render())
    assert any("acknowledged" in e.text for e in app.board.events)


async def test_unacknowledged_command_is_resent_with_the_same_seq_then_fails(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm, clock: FakeClock
) -> None:
    app, pilot = two_agents
    await pilot.press("down", "t")  # bravo is in MISSION: TAKEOFF will be rejected
    ((channel, first),) = await wait_sent(pilot, app, swarm, 1)
    assert channel == "bravo/OPERATOR_CMD"
    clock.advance(1.0)
    sent = await wait_sent(pilot, app, swarm, 2)
    assert sent[1][1].header.seq == first.header.seq and sent[1][0] == channel
    assert sent[1][1].header.utime > first.header.utime  # fresh time for the replay window
    for _ in range(4):
        clock.advance(1.0)
        swarm.mc("bravo", mc_state_t.MISSION)  # alive, but not accepting it
        await until(pilot, app, lambda: app.board.agents["bravo"].last_heard == clock())
    cmd = next(c for c in app.tracker.done if c.seq == first.header.seq)
    assert cmd.status is Status.FAILED and cmd.sends == 5
    assert "likely rejected it (MC MISSION; TAKEOFF applies in STANDBY)" in cmd.reason
    assert "FAILED" in str(app.screen.query_one("#commands").render())
    clock.advance(3.0)
    app.refresh_now()
    await settle(pilot)
    assert len(swarm.sent()) == 5  # no resend after failure
    assert app.tracker.counts()[Status.FAILED] == 1


async def test_all_agent_command_waits_for_every_agent(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm
) -> None:
    app, pilot = two_agents
    await pilot.press("R", "y")
    ((channel, msg),) = await wait_sent(pilot, app, swarm, 1)
    assert channel == "SWARM/OPERATOR_CMD" and msg.target == ""
    cmd = app.tracker.pending[msg.header.seq]
    assert cmd.expected == {"alpha", "bravo"}
    swarm.mc("bravo", mc_state_t.RTL, last=msg.header.seq)
    await until(pilot, app, lambda: cmd.acked == {"bravo"})
    assert cmd.status is Status.PENDING and "1/2" in str(app.screen.query_one("#commands").render())
    swarm.mc("alpha", mc_state_t.STANDBY, last=msg.header.seq)
    await until(pilot, app, lambda: cmd.status is Status.ACKED)


async def test_no_selection_sends_nothing(context: Context, swarm: FakeSwarm, clock: FakeClock) -> None:
    app = make_app(context, clock)
    async with app.run_test(size=(120, 36)) as pilot:
        await pilot.press("t", "d", "space")
        await settle(pilot)
        assert swarm.sent() == [] and swarm.sent_directions() == []


# ---------------------------------------------------------------------- direction
async def test_direction_keys(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm, clock: FakeClock
) -> None:
    app, pilot = two_agents
    await pilot.press("d", "d", "a", "right", "w", "w", "s", "space")
    dirs = await wait_dirs(pilot, app, swarm, 8)
    assert {ch for ch, _ in dirs} == {"alpha/DIRECTION_CMD"} and {m.target for _, m in dirs} == {"alpha"}
    assert [(m.active, round(m.azimuth), m.speed) for _, m in dirs] == [
        (True, 15, 1.0),
        (True, 30, 1.0),
        (True, 15, 1.0),
        (True, 30, 1.0),
        (True, 30, 1.5),
        (True, 30, 2.0),
        (True, 30, 1.5),
        (False, 30, 1.5),
    ]
    assert [m.header.seq for _, m in dirs] == list(range(1, 9))
    # D switches the direction keys to every agent, after confirmation.
    await pilot.press("D")
    assert isinstance(app.screen, ConfirmScreen)
    await pilot.press("y", "a")
    dirs = await wait_dirs(pilot, app, swarm, 9)
    assert (
        dirs[-1][0] == "SWARM/DIRECTION_CMD" and dirs[-1][1].target == "" and round(dirs[-1][1].azimuth) == 15
    )
    assert dirs[-1][1].active
    # The latest direction is repeated (no ack exists for directions).
    clock.advance(1.0)
    dirs = await wait_dirs(pilot, app, swarm, 10)
    assert dirs[-1][0] == "SWARM/DIRECTION_CMD" and round(dirs[-1][1].azimuth) == 15
    await pilot.press("D")  # back to the selected agent: no confirmation needed
    assert not isinstance(app.screen, ConfirmScreen) and not app.direction_all


def keyed_app(context: Context, clock: FakeClock, swarm: FakeSwarm) -> tuple[OperatorApp, str]:
    """A console with a swarm key, and the fake swarm signing with the same key on its clock."""
    key = "correct horse battery staple"
    swarm.key, swarm.clock = key, clock
    return make_app(context, clock, memq_config(security={"swarm_key": key})), key


# ---------------------------------------------------------------------- security, help
async def test_commands_are_signed_when_a_swarm_key_is_configured(
    context: Context, swarm: FakeSwarm, clock: FakeClock
) -> None:
    app, key = keyed_app(context, clock, swarm)
    async with app.run_test(size=(160, 44)) as pilot:
        swarm.agent("alpha")
        await until(pilot, app, lambda: app.selected == "alpha")
        await pilot.press("t", "d")
        clock.advance(1.0)  # resend: same seq, new utime, new MAC
        sent = await wait_sent(pilot, app, swarm, 2)
        dirs = await wait_dirs(pilot, app, swarm, 1)
    for msg in [m for _, m in sent] + [m for _, m in dirs]:
        assert msg.header.mac_len == 32
        assert verify(msg, key, 5.0, now=msg.header.utime / 1e6) is None
        assert verify(msg, "another key", 5.0, now=msg.header.utime / 1e6) is not None
    assert sent[0][1].header.seq == sent[1][1].header.seq and bytes(sent[0][1].header.mac) != bytes(
        sent[1][1].header.mac
    )


async def test_a_keyed_console_takes_no_forged_acknowledgement_or_state(
    context: Context, swarm: FakeSwarm, clock: FakeClock
) -> None:
    """An attacker's unsigned or wrongly signed mc_state_t must not acknowledge a command the MC never
    accepted (the console would stop resending it) nor change what the operator sees."""
    app, key = keyed_app(context, clock, swarm)
    async with app.run_test(size=(160, 44)) as pilot:
        swarm.agent("alpha")
        await until(pilot, app, lambda: app.selected == "alpha")
        await pilot.press("t")
        ((_, msg),) = await wait_sent(pilot, app, swarm, 1)
        cmd = app.tracker.pending[msg.header.seq]
        for forger in (None, "another key"):
            swarm.key = forger
            swarm.mc("alpha", mc_state_t.TAKEOFF, last=msg.header.seq)
            await settle(pilot)
            app.refresh_now()
            assert cmd.status is Status.PENDING
            assert app.board.agents["alpha"].mc_state == "STANDBY"
        assert app.node.rejected == 2
        swarm.key = key  # the real MC's acknowledgement
        swarm.mc("alpha", mc_state_t.TAKEOFF, last=msg.header.seq)
        await until(pilot, app, lambda: cmd.status is Status.ACKED)
        assert app.board.agents["alpha"].mc_state == "TAKEOFF"


async def test_help_screen_and_footer(two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm) -> None:
    app, pilot = two_agents
    footer = {a.binding.key for a in app.screen.active_bindings.values() if a.binding.show}
    assert {"t", "T", "l", "L", "r", "R", "a", "d", "w", "s", "space", "D", "question_mark", "q"} <= footer
    await pilot.press("question_mark")
    assert isinstance(app.screen, HelpScreen)
    await pilot.press("t")
    await pilot.press("escape")
    assert not isinstance(app.screen, HelpScreen)
    await settle(pilot)
    assert swarm.sent() == []


# ---------------------------------------------------------------------- robustness and the entry point
async def test_a_key_goes_before_a_pending_bulk_update(
    context: Context, swarm: FakeSwarm, clock: FakeClock
) -> None:
    """Keys are handled before bulk updates: with a tick's worth of datagrams from a large swarm
    pending, the timer's refresh yields between slices and a key's command goes out in between."""
    app = make_app(context, clock, refresh_interval=3600.0)  # only the refresh this test starts
    async with app.run_test(size=(160, 44)) as pilot:
        swarm.agent("alpha")
        await until(pilot, app, lambda: app.selected == "alpha")
        n = 16 * SLICE_ITEMS  # each is logged as discovered: fewer than the 2,000 events the board keeps
        for i in range(n):
            swarm.mc(f"bulk{i:04d}")
        deadline = time.monotonic() + 10.0
        while len(app.node.latest) < n:  # delivered to the node, not yet folded in
            assert time.monotonic() < deadline, "the bulk never reached the console"
            await asyncio.sleep(0.02)
        tick = asyncio.ensure_future(app.refresh_sliced())
        await pilot.press("t")
        await tick
        assert len(app.board.agents) == n + 1
        events = list(app.board.events)
        (sent,) = [i for i, ev in enumerate(events) if ev.text.startswith("sent TAKEOFF → alpha")]
        discovered = [i for i, ev in enumerate(events) if ev.kind is EventKind.DISCOVERED]
        assert discovered[0] < sent < discovered[-1], "the key waited for the whole bulk update"


async def test_the_map_is_fixed_rate_and_repaints_only_when_its_picture_changes(
    two_agents: tuple[OperatorApp, Any], swarm: FakeSwarm, clock: FakeClock
) -> None:
    app, pilot = two_agents
    swarm_map = app.screen.query_one(SwarmMap)
    points = points_from(app.board.positions())
    swarm_map.update_points(points, app.selected)
    repaints = swarm_map.repaints
    # Agents moving inside their cells: the aggregated picture is the same, nothing is repainted.
    nudged = [dataclasses.replace(p, north=p.north + 0.01, east=p.east - 0.01) for p in points]
    swarm_map.update_points(nudged, app.selected)
    assert swarm_map.repaints == repaints
    turned = [dataclasses.replace(p, heading=p.heading + 180.0) for p in points]
    swarm_map.update_points(turned, app.selected)
    assert swarm_map.repaints == repaints + 1

    # The timer's refresh takes positions in once per map_interval; refresh_now() at once.
    app.refresh_now()
    shown = swarm_map.points
    swarm.tel("bravo", lat=47.3990, lon=8.5470, heading=90.0)
    await until(pilot, app, lambda: telemetry(app, "bravo").lat == 47.3990)
    assert swarm_map.points != shown
    shown = swarm_map.points
    swarm.tel("bravo", lat=47.3995, lon=8.5475, heading=90.0)
    deadline = time.monotonic() + 5.0
    while telemetry(app, "bravo").lat != 47.3995:
        assert time.monotonic() < deadline
        await app.refresh_sliced()
        await pilot.pause(0.02)
    assert swarm_map.points == shown, "not before map_interval has passed"
    clock.advance(ConsoleSettings().map_interval)
    await app.refresh_sliced()
    assert swarm_map.points != shown


async def test_off_screen_telemetry_is_decoded_when_shown(
    context: Context, swarm: FakeSwarm, clock: FakeClock
) -> None:
    """The timer's refresh decodes the telemetry of agents on screen (table rows, selection) and
    keeps only the newest datagram of the others until the map takes every position in."""
    app = make_app(context, clock, refresh_interval=3600.0)  # only the refreshes this test runs
    async with app.run_test(size=(160, 44)) as pilot:
        names = [f"uav{i:02d}" for i in range(60)]  # more rows than the table shows
        for name in names:
            swarm.agent(name, battery=90.0)
        await until(
            pilot,
            app,
            lambda: len(app.board.agents) == 60 and all(v.telemetry for v in app.board.agents.values()),
        )
        await pilot.pause()
        shown, hidden = names[0], names[-1]
        assert hidden not in app.screen.query_one(AgentTable).visible_names()
        heard = app.board.agents[hidden].messages
        for name in (shown, hidden):
            swarm.tel(name, battery=50.0)
        deadline = time.monotonic() + 5.0
        while len(app.node.latest) < 2:
            assert time.monotonic() < deadline, "the telemetry never reached the console"
            await asyncio.sleep(0.02)
        await app.refresh_sliced()
        assert telemetry(app, shown).battery == 50.0
        assert telemetry(app, hidden).battery == 90.0, "off screen: not decoded yet"
        assert app.board.agents[hidden].messages == heard + 1, "but heard"
        clock.advance(ConsoleSettings().map_interval)
        await app.refresh_sliced()
        assert telemetry(app, hidden).battery == 50.0, "the map's turn: every position"


async def test_appending_events_does_not_lay_out_the_screen(two_agents: tuple[OperatorApp, Any]) -> None:
    app, pilot = two_agents
    log_widget = app.screen.query_one(EventLog)
    for i in range(40):  # more lines than the log shows: its scrollbar is up
        app.board.log(WALL0, "alpha", f"line {i}")
    app.refresh_now()
    await pilot.pause()
    skipped = log_widget.layouts_skipped
    app.board.log(WALL0, "alpha", "one more line")
    app.refresh_now()
    await pilot.pause()
    assert log_widget.layouts_skipped == skipped + 1
    assert log_widget.scroll_y == log_widget.max_scroll_y, "still following the newest line"
    assert log_widget.lines[-1].text.endswith("one more line")


async def test_garbage_on_a_watched_channel_is_reported_not_fatal(
    two_agents: tuple[OperatorApp, Any], context: Context
) -> None:
    app, pilot = two_agents
    context.buses.publish("lan", "alpha/MC_STATE", b"\x00garbage")
    await until(pilot, app, lambda: any("not a valid mc_state_t" in e.text for e in app.board.events))
    assert app.node.decode_errors == 1 and app.is_running


def test_run_reports_a_missing_multicast_route() -> None:
    """`antalate tui` on a host without a multicast route: one clear error, exit status 2, no UI."""
    proc = run_unrouted([sys.executable, "-m", "operator_tui", "--headless", "1"], timeout=30)
    assert proc.returncode == 2
    assert "no route for multicast" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.netns
def test_run_headless_on_udp_multicast(netns: NetNamespace) -> None:
    """The entry the CLI calls, on real UDP multicast in a private namespace: starts and exits cleanly."""
    proc = netns.run([sys.executable, "-m", "operator_tui", "--headless", "1"], timeout=30)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
