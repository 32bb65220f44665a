"""The console's pure parts: the swarm board, the command tracker, direction control, row and map formats."""

from __future__ import annotations

import random

import pytest

from antalate_lcm.msgs import arbiter_status_t, hlc_error_t, hlc_state_t, mc_state_t, telemetry_t
from antalate_lcm.wire.vocabulary import Severity
from operator_tui.board import EventKind, SafetySummary, SwarmBoard, heading_arrow, natural_key
from operator_tui.commands import CommandTracker, DirectionControl, Status, TrackedCommand, applies
from operator_tui.widgets.agent_table import format_age, row_cells
from operator_tui.widgets.swarm_map import MapPoint, render_map


def status_of(cmd: TrackedCommand) -> Status:
    """The status read afresh: mypy keeps ``cmd.status`` narrowed by an earlier assert across the calls
    that change it."""
    return cmd.status


def mc(state: int, last: int = 0) -> mc_state_t:
    m = mc_state_t()
    m.state, m.last_command_seq = state, last
    return m


def hlc(state: int) -> hlc_state_t:
    m = hlc_state_t()
    m.state, m.autopilot = state, "sim"
    return m


def tel(
    lat: float = 47.0, lon: float = 8.0, alt: float = 10.0, heading: float = 90.0, battery: float = 80.0
) -> telemetry_t:
    m = telemetry_t()
    m.lat, m.lon, m.alt, m.heading, m.vn, m.ve, m.battery, m.mode = (
        lat,
        lon,
        alt,
        heading,
        3.0,
        4.0,
        battery,
        "SIM",
    )
    return m


# ---------------------------------------------------------------------- board
def test_model_folds_messages_and_logs_only_transitions() -> None:
    board = SwarmBoard()
    for t in (0.0, 0.2, 0.4):  # periodic republish: one transition, not three
        board.apply("MC_STATE", "a", mc(mc_state_t.STANDBY, last=7), t, 1000 + t)
    board.apply("HLC_STATE", "a", hlc(hlc_state_t.READY), 0.5, 1000.5)
    board.apply("MC_STATE", "a", mc(mc_state_t.TAKEOFF, last=8), 0.6, 1000.6)
    view = board.agents["a"]
    assert (view.mc_state, view.hlc_state, view.last_command_seq, view.autopilot) == (
        "TAKEOFF",
        "READY",
        8,
        "sim",
    )
    texts = [(e.kind, e.text) for e in board.take_events()]
    assert texts == [
        (EventKind.DISCOVERED, "discovered (first heard on MC_STATE)"),  # first states: in the table only
        (EventKind.MC, "MC STANDBY → TAKEOFF"),
    ]
    board.apply("HLC_STATE", "b", hlc(hlc_state_t.LLC_DOWN), 0.7, 1000.7)  # a bad first state is news
    assert [(e.kind, e.text, e.severity) for e in board.take_events()][1:] == [
        (EventKind.HLC, "HLC — → LLC_DOWN", Severity.CRITICAL)
    ]
    assert board.take_events() == []


def test_model_errors_arbiters_and_unknown_states() -> None:
    board = SwarmBoard()
    err = hlc_error_t()
    err.code, err.severity, err.text = 12, hlc_error_t.ERROR, "arming refused"
    board.apply("HLC_ERROR", "a", err, 1.0, 1001.0)
    arb = arbiter_status_t()
    arb.arbiter, arb.state, arb.n, arb.active = "main", "MISSION", 2, ["swarm", "video"]
    arb.n_failed, arb.failed = 1, ["camera: ffmpeg died"]
    board.apply("ARBITER", "a", arb, 1.1, 1001.1, {"agent": "a", "arbiter": "main"})
    board.apply("HLC_STATE", "a", hlc(42), 1.2, 1001.2)  # a newer agent's state is shown, not dropped
    view = board.agents["a"]
    assert view.last_error is not None and (view.last_error.code, view.last_error.text) == (
        12,
        "arming refused",
    )
    assert view.last_error.severity is Severity.ERROR
    assert view.active_behaviors == ("swarm", "video") and view.failed_behaviors == ("camera: ffmpeg died",)
    assert view.hlc_state == "?42"
    kinds = [e.kind for e in board.take_events()]
    assert kinds.count(EventKind.ERROR) == 1 and kinds.count(EventKind.BEHAVIOR) == 1
    board.apply("ARBITER", "a", arb, 1.3, 1001.3)  # the same failure republished is not logged again
    assert not [e for e in board.take_events() if e.kind is EventKind.BEHAVIOR]


def test_the_latest_safety_report_is_kept_apart_and_shown_in_the_detail() -> None:
    from operator_tui.widgets.panels import detail_text

    board = SwarmBoard()
    safety = hlc_error_t()
    safety.code, safety.severity = 14, hlc_error_t.WARNING
    safety.text = "safety: velocity modified by separation; nearest b at 3.12 m"
    board.apply("HLC_ERROR", "a", safety, 1.0, 1001.0)
    other = hlc_error_t()
    other.code, other.severity, other.text = 7, hlc_error_t.ERROR, "autopilot LAND failed"
    board.apply("HLC_ERROR", "a", other, 2.0, 1002.0)
    view = board.agents["a"]
    assert view.last_safety is not None and view.last_safety.text.endswith("nearest b at 3.12 m")
    assert view.last_error is not None and view.last_error.code == 7
    text = detail_text(view, 2.0).plain
    assert "safety " in text and "modified by separation; nearest b at 3.12 m" in text
    assert "autopilot LAND failed" in text


def test_the_status_bar_says_who_is_being_modified_and_the_closest_pair_in_the_air() -> None:
    """docs/safety.md: the swarm-wide line -- how many commands the filter is modifying (by whom) and
    the closest pair of agents in the air (3-D); nothing for a swarm that never sent a SAFETY report."""
    from antalate_lcm.base.geo import offset
    from operator_tui.commands import DirectionControl
    from operator_tui.widgets.panels import status_text

    board = SwarmBoard()
    where = {"a": (0.0, 0.0, 10.0), "b": (3.0, 4.0, 10.0), "c": (0.0, 1.0, 0.0), "d": (100.0, 0.0, 10.0)}
    for name, (north, east, alt) in where.items():
        m = tel(*offset(47.0, 8.0, north, east), alt=alt)
        m.in_air = alt > 0  # c stands on the ground beside a: not a pair in the air
        board.apply("TELEMETRY", name, m, 0.0, 1000.0)
    assert board.safety_summary(0.0) is None  # no SAFETY report heard: no filter, no line

    def report(agent: str, text: str, at: float) -> None:
        e = hlc_error_t()
        e.code, e.severity, e.text = 14, hlc_error_t.WARNING, text
        board.apply("HLC_ERROR", agent, e, at, 1000.0 + at)

    report("a", "safety: velocity modified by separation; nearest b at 5.00 m", 1.0)
    report("b", "safety: velocity modified by separation; nearest a at 5.00 m", 1.5)
    report("d", "safety: velocity modified by fence; nearest a at 100.00 m", 0.2)  # 2.8 s old at 3.0
    summary = board.safety_summary(3.0)
    assert summary is not None
    assert summary.modified == {"separation": 2}
    assert summary.closest is not None and summary.closest[1:] == ("a", "b")
    assert summary.closest[0] == pytest.approx(5.0, abs=0.01)

    def status(safety: SafetySummary) -> str:
        """The status line of a calm swarm of four, but for ``safety``."""
        return status_text(
            bus="memq://",
            agents=4,
            stale=0,
            pending=0,
            failed=0,
            direction=DirectionControl(),
            scope_all=True,
            selected=None,
            safety=safety,
        ).plain

    assert status(summary).endswith("safety modifying 2 by separation  closest a-b 5.0 m")
    later = board.safety_summary(10.0)
    assert later is not None and later.modified == {}
    assert "safety idle" in status(later)


def test_stale_agents_are_marked_once_and_kept() -> None:
    board = SwarmBoard(stale_after=3.0)
    board.apply("MC_STATE", "a", mc(1), 0.0, 1000.0)
    board.apply("MC_STATE", "b", mc(1), 0.0, 1000.0)
    board.take_events()
    board.apply("MC_STATE", "b", mc(1), 2.9, 1002.9)
    board.tick(3.1, 1003.1)
    board.tick(5.0, 1005.0)
    assert board.agents["a"].stale and not board.agents["b"].stale
    assert [(e.agent, e.kind) for e in board.take_events()] == [("a", EventKind.STALE)]
    assert board.live_names() == ["b"] and board.names() == ["a", "b"] and board.stale_count == 1
    board.apply("TELEMETRY", "a", tel(), 6.0, 1006.0)
    assert not board.agents["a"].stale
    assert [e.kind for e in board.take_events()] == [EventKind.ALIVE]


def test_positions_are_metres_from_the_first_fix() -> None:
    board = SwarmBoard()
    board.apply("TELEMETRY", "a", tel(lat=0.0, lon=0.0), 0.0, 0.0)  # no fix yet: not the origin
    board.apply("TELEMETRY", "b", tel(lat=47.0, lon=8.0), 0.0, 0.0)
    board.apply("TELEMETRY", "c", tel(lat=47.001, lon=8.0), 0.0, 0.0)
    pos = {v.name: (round(n), round(e)) for v, n, e in board.positions()}
    assert pos == {"b": (0, 0), "c": (111, 0)}
    assert board.agents["b"].telemetry is not None and board.agents[
        "b"
    ].telemetry.ground_speed == pytest.approx(5.0)


def test_natural_order_and_arrows() -> None:
    assert sorted(["uav10", "uav2", "uav1", "alpha"], key=natural_key) == ["alpha", "uav1", "uav2", "uav10"]
    assert [heading_arrow(h) for h in (0, 44, 46, 90, 180, 270, 359, -90)] == [
        "↑",
        "↗",
        "↗",
        "→",
        "↓",
        "←",
        "↑",
        "←",
    ]
    assert heading_arrow(float("nan")) == "?"


# ---------------------------------------------------------------------- command tracker
def test_ack_is_equality_of_last_command_seq() -> None:
    tr = CommandTracker(first_seq=500)
    cmd = tr.new("TAKEOFF", "a", 0.0, expected=[])
    assert cmd.seq == 500 and cmd.expected == {"a"}
    assert tr.observe("a", 900, 0.1) == []  # another sender's larger seq proves nothing about ours
    assert tr.observe("b", 500, 0.1) == []  # not the target
    (update,) = tr.observe("a", 500, 0.3)
    assert cmd.status is Status.ACKED and "acknowledged after 0.3 s" in update.text
    assert tr.pending == {} and list(tr.done) == [cmd]


def test_resend_keeps_the_seq_then_fails_with_a_likely_reason() -> None:
    tr = CommandTracker(resend_interval=1.0, timeout=3.0, first_seq=10)
    cmd = tr.new("LAND", "a", 0.0, expected=[])
    assert tr.tick(0.5) == ([], [])
    resend, _ = tr.tick(1.0)
    assert resend == [cmd] and cmd.seq == 10 and cmd.sends == 2
    assert tr.tick(1.5) == ([], [])
    assert tr.tick(2.0)[0] == [cmd]
    _, (update,) = tr.tick(3.0, mc_state_of=lambda a: "STANDBY")
    assert cmd.status is Status.FAILED and update.failed
    assert "a likely rejected it (MC STANDBY; LAND applies in HOLD/MISSION/RTL/TAKEOFF)" in cmd.reason
    assert "3 sends" in cmd.reason
    (late,) = tr.observe("a", 10, 7.0)  # the link came back: it had been accepted after all
    assert status_of(cmd) is Status.ACKED and cmd.reason == "acked late (7.0 s)" and "late" in late.text
    assert tr.observe("a", 10, 7.2) == []
    other = tr.new("LAND", "b", 10.0, expected=[])
    tr.tick(13.0, mc_state_of=lambda a: "MISSION", is_stale=lambda a: True)
    assert "b is silent" in other.reason
    third = tr.new("RTL", "c", 20.0, expected=[])
    tr.tick(23.0, mc_state_of=lambda a: "MISSION")
    assert "c: no ack (lost, or rejected)" in third.reason


def test_broadcast_waits_for_every_live_agent() -> None:
    tr = CommandTracker(timeout=5.0, first_seq=1)
    cmd = tr.new("RTL", "", 0.0, expected=["a", "b", "c"])
    assert cmd.broadcast and cmd.label == "RTL → ALL (3)"
    tr.observe("a", 1, 0.1)
    tr.observe("z", 1, 0.1)  # an agent unknown when sent: counted, not required
    assert cmd.status is Status.PENDING and cmd.missing == ["b", "c"]
    tr.observe("b", 1, 0.2)
    _, (update,) = tr.tick(5.0)
    assert status_of(cmd) is Status.FAILED
    assert cmd.reason.startswith("2/3 acked") and "c: no ack" in cmd.reason and update.failed
    ok = tr.new("LAND", "", 6.0, expected=["a", "b"])
    tr.observe("a", ok.seq, 6.1)
    tr.observe("b", ok.seq, 6.2)
    assert ok.status is Status.ACKED


def test_broadcast_with_no_known_agent_counts_whoever_acks() -> None:
    tr = CommandTracker(timeout=2.0, first_seq=1)
    cmd = tr.new("TAKEOFF", "", 0.0, expected=[])
    tr.observe("a", 1, 0.5)
    assert cmd.status is Status.PENDING
    tr.tick(2.0)
    assert status_of(cmd) is Status.ACKED
    lonely = tr.new("TAKEOFF", "", 3.0, expected=[])
    tr.tick(5.0)
    assert lonely.status is Status.FAILED and "none was known" in lonely.reason


def test_a_later_ack_supersedes_an_earlier_command() -> None:
    tr = CommandTracker(first_seq=1)
    first = tr.new("TAKEOFF", "a", 0.0, expected=[])
    second = tr.new("LAND", "a", 0.5, expected=[])
    updates = tr.observe("a", second.seq, 0.6)
    assert first.status is Status.ACKED and first.reason == "superseded by #2"
    assert second.status is Status.ACKED and len(updates) == 2


def test_first_seq_is_random_and_seqs_increase() -> None:
    a = CommandTracker(rng=random.Random(1))
    b = CommandTracker(rng=random.Random(2))
    sa = [a.new("RTL", "x", 0.0, expected=[]).seq for _ in range(3)]
    assert sa[1] == sa[0] + 1 and sa[2] == sa[0] + 2
    assert b.new("RTL", "x", 0.0, expected=[]).seq != sa[0]
    with pytest.raises(ValueError):
        a.new("FLIP", "x", 0.0, expected=[])


def test_recent_lists_finished_then_pending() -> None:
    tr = CommandTracker(first_seq=1)
    done = tr.new("RTL", "a", 0.0, expected=[])
    tr.observe("a", 1, 0.1)
    pending = tr.new("LAND", "b", 0.2, expected=[])
    assert tr.recent(5) == [done, pending] and tr.recent(1) == [pending] and tr.recent(0) == []
    assert tr.counts() == {Status.PENDING: 1, Status.ACKED: 1, Status.FAILED: 0}


def test_applies_follows_the_mc_table() -> None:
    assert applies("TAKEOFF", "STANDBY") is True
    assert applies("TAKEOFF", "MISSION") is False
    assert applies("LAND", None) is None


def test_direction_control() -> None:
    d = DirectionControl(speed=1.0, max_speed=2.0, repeat_interval=1.0)
    assert not d.active and not d.due(100.0)
    d.rotate(-1)
    assert d.azimuth == 345.0 and d.active
    d.rotate(2)
    assert d.azimuth == 15.0
    for _ in range(5):
        d.change_speed(1)
    assert d.speed == 2.0
    for _ in range(6):
        d.change_speed(-1)
    assert d.speed == 0.0
    d.stop()
    assert not d.active
    d.sent("", 10.0)
    assert not d.due(10.5) and d.due(11.0)
    assert d.describe() == "stopped 015° 0.0 m/s → ALL"


# ---------------------------------------------------------------------- formats
def test_row_cells_colour_states_and_dim_stale_agents() -> None:
    board = SwarmBoard(stale_after=3.0)
    board.apply("MC_STATE", "a", mc(mc_state_t.MISSION), 0.0, 0.0)
    board.apply("HLC_STATE", "a", hlc(hlc_state_t.GAINING_ALTITUDE), 0.0, 0.0)
    board.apply("TELEMETRY", "a", tel(battery=15.0, heading=92.0), 0.0, 0.0)
    cells = dict(
        zip(
            ("agent", "mc", "hlc", "batt", "alt", "spd", "hdg", "link"),
            row_cells(board.agents["a"], 0.5, 3.0),
            strict=False,
        )
    )
    assert cells["mc"] == ("MISSION", "bold green")
    assert cells["hlc"] == ("GAINING_ALT", "yellow")
    assert cells["batt"] == ("15%", "bold red")
    assert cells["alt"][0] == "10.0" and cells["spd"][0] == "5.0" and cells["hdg"][0] == "092→"
    assert cells["link"] == ("ok", "green")
    board.tick(4.0, 4.0)
    stale = row_cells(board.agents["a"], 4.0, 3.0)
    assert stale[1] == ("MISSION", "bold green dim") and stale[7] == ("4s", "bold red")
    assert [format_age(x) for x in (0.2, 1.4, 59, 600, 7200)] == ["ok", "1s", "59s", "10m", "2h"]
    nan = float("nan")
    board.apply("TELEMETRY", "n", tel(lat=nan, lon=nan, alt=nan, heading=nan, battery=nan), 5.0, 5.0)
    assert row_cells(board.agents["n"], 5.0, 3.0)[6] == ("nan?", "")  # shown, never a crash
    assert [v.name for v, _, _ in board.positions()] == ["a"]


def test_map_draws_arrows_counts_label_and_scale() -> None:
    points = [
        MapPoint("a", 0.0, 0.0, 90.0, "MISSION", False),
        MapPoint("b", 100.0, 100.0, 0.0, "STANDBY", False),
        MapPoint("c", 100.0, 100.0, 0.0, "STANDBY", False),
        MapPoint("d", -100.0, -100.0, 0.0, "RTL", True),
    ]
    text = render_map(points, "a", 40, 12)
    lines = text.plain.split("\n")
    assert len(lines) == 12 and all(len(line) <= 40 for line in lines)
    body = "\n".join(lines[:-1])
    assert "→ a" in body  # the selected agent, labelled
    assert "2" in body  # b and c share a cell
    assert "×" in body  # d is stale
    row_b = next(i for i, line in enumerate(lines) if "2" in line)
    row_d = next(i for i, line in enumerate(lines) if "×" in line)
    assert row_b < row_d and lines[row_b].index("2") > lines[row_d].index("×")  # NE is up and right of SW
    assert lines[-1].startswith("├") and " m  N↑  4 shown" in lines[-1]
    assert render_map([], None, 5, 2).plain == ""
