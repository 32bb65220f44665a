"""The operator console shows the failsafe states (MC HOLD and HLC_LOST, HLC HOLD) and why (issue 12)."""

from __future__ import annotations

from antalate_lcm.msgs import hlc_state_t, mc_state_t
from antalate_lcm.wire.vocabulary import Severity
from operator_tui.board import EventKind, SwarmBoard
from operator_tui.commands import applies
from operator_tui.widgets.palette import HLC_STYLE, MC_STYLE, UNKNOWN_STYLE, hlc_style, mc_style
from operator_tui.widgets.panels import detail_text


def mc(state: int, reason: str = "") -> mc_state_t:
    m = mc_state_t()
    m.state, m.reason, m.last_command_seq = state, reason, 1
    return m


def hlc(state: int, reason: str = "") -> hlc_state_t:
    m = hlc_state_t()
    m.state, m.reason, m.autopilot = state, reason, "sim"
    return m


def test_every_state_has_a_colour() -> None:
    for name in ("HOLD", "HLC_LOST", "ERROR"):
        assert name in MC_STYLE and mc_style(name) != UNKNOWN_STYLE
    assert "HOLD" in HLC_STYLE and hlc_style("HOLD") != UNKNOWN_STYLE
    for name in MC_STYLE:
        assert hasattr(mc_state_t, name)
    for name in HLC_STYLE:
        assert hasattr(hlc_state_t, name)


def test_failsafe_states_are_events_with_their_reason() -> None:
    board = SwarmBoard()
    board.apply("MC_STATE", "a", mc(mc_state_t.MISSION), 0.0, 1000.0)
    board.apply("HLC_STATE", "a", hlc(hlc_state_t.AIRBORNE), 0.0, 1000.0)
    board.take_events()
    fence = "autopilot failsafe: holding position (fence breach; autopilot switched to BRAKE)"
    board.apply("HLC_STATE", "a", hlc(hlc_state_t.HOLD, fence), 1.0, 1001.0)
    board.apply("MC_STATE", "a", mc(mc_state_t.HOLD, "vehicle holding on its own (HLC HOLD)"), 1.1, 1001.1)
    lost = "HLC lost (HLC silent for 2.1 s; the vehicle is on its own GCS failsafe)"
    board.apply("MC_STATE", "a", mc(mc_state_t.HLC_LOST, lost), 4.0, 1004.0)
    events = [(e.kind, e.text, e.severity) for e in board.take_events()]
    assert events == [
        (EventKind.HLC, f"HLC AIRBORNE → HOLD: {fence}", Severity.WARNING),
        (EventKind.MC, "MC MISSION → HOLD: vehicle holding on its own (HLC HOLD)", Severity.WARNING),
        (EventKind.MC, f"MC HOLD → HLC_LOST: {lost}", Severity.ERROR),
    ]
    view = board.agents["a"]
    assert (view.mc_state, view.mc_reason, view.hlc_reason) == ("HLC_LOST", lost, fence)
    shown = detail_text(view, 4.0).plain
    assert "HLC_LOST" in shown and "GCS failsafe" in shown and "fence breach" in shown


def test_command_hints_follow_the_new_rows() -> None:
    assert applies("LAND", "HOLD") and applies("RTL", "HOLD") and applies("LAND", "RTL")
    assert not applies("RTL", "HLC_LOST") and not applies("LAND", "HLC_LOST")
    assert not applies("TAKEOFF", "HOLD")
