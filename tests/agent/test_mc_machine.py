"""Mission Control state machine: every row of docs/design.md §5 (written out here independently of the
implementation's table), the documented extra rows, rejections, duplicates, the takeoff timeout, and the
failsafe rows: link regained by policy, HOLD, HLC_LOST and its resync, following the vehicle's failsafes."""

from __future__ import annotations

from dataclasses import FrozenInstanceError
from typing import Any

import pytest

from antalate_lcm.agent.mc.machine import (
    MC_TABLE,
    McEvent,
    McOutcome,
    McParams,
    MissionControl,
)
from antalate_lcm.msgs import operator_cmd_t
from antalate_lcm.wire.vocabulary import Command, HlcState, McState

M = McState
H = HlcState
C = Command
T0 = 1000.0

# -------------------------------------------------------------------------------- helpers


def state_of(mc: MissionControl) -> McState:
    """The state read afresh: mypy keeps ``mc.state`` narrowed by an earlier assert across the calls
    that change it."""
    return mc.state


def mc_in(state: McState, params: McParams | None = None) -> MissionControl:
    """An MC driven into `state` through legitimate inputs (so internal bookkeeping is realistic)."""
    mc = MissionControl(params)
    if state is M.INIT:
        return mc
    if state is M.ERROR:
        mc.on_hlc_state(H.LLC_DOWN, T0)
        assert mc.state is M.ERROR
        return mc
    if state is M.HLC_LOST:
        mc = mc_in(M.MISSION, params)
        mc.tick(T0 + 1.5 + mc.params.hlc_timeout)
        assert mc.state is M.HLC_LOST
        return mc
    if state is M.HOLD:
        mc = mc_in(M.MISSION, params)
        mc.on_hlc_state(H.HOLD, T0 + 1)
        assert mc.state is M.HOLD
        return mc
    mc.on_hlc_state(H.READY, T0)
    if state is not M.STANDBY:
        assert mc.on_command(C.TAKEOFF, 1, T0, sender="op").accepted
        if state is not M.TAKEOFF:
            mc.on_hlc_state(H.TAKEOFF, T0 + 0.1)
            mc.on_hlc_state(H.GAINING_ALTITUDE, T0 + 0.2)
            mc.on_hlc_state(H.AIRBORNE, T0 + 0.3)
            if state is M.RTL:
                mc.on_command(C.RTL, 2, T0 + 1, sender="op")
            elif state is M.LAND:
                mc.on_command(C.LAND, 2, T0 + 1, sender="op")
            elif state is M.MANUAL:
                mc.on_hlc_state(H.MANUAL, T0 + 1)
    assert mc.state is state
    return mc


Input = tuple[str, object]  # ("hlc", HlcState) | ("op", Command) | ("timeout", None)


def feed(mc: MissionControl, what: Input, now: float = T0 + 2) -> McOutcome:
    kind, value = what
    if kind == "hlc":
        assert isinstance(value, HlcState)
        return mc.on_hlc_state(value, now)
    if kind == "op":
        assert isinstance(value, Command)
        return mc.on_command(value, 99, now, sender="op")
    if kind == "silence":
        return mc.tick(now + mc.params.hlc_timeout)
    # The takeoff acknowledgement timeout: the HLC keeps republishing READY meanwhile.
    mc.on_hlc_state(mc.hlc_state if mc.hlc_state is not None else H.READY, now + 60.0)
    return mc.tick(now + 60.0)


def hlc(s: HlcState) -> Input:
    return ("hlc", s)


def op(c: Command) -> Input:
    return ("op", c)


TIMEOUT: Input = ("timeout", None)
SILENCE: Input = ("silence", None)  # no hlc_state_t for hlc_timeout
FLYING_MC = (M.TAKEOFF, M.MISSION, M.RTL, M.LAND)
RESYNC = (M.INIT, M.HLC_LOST)

# docs/design.md §5, row by row, expanded to (from, input, to).
DESIGN_ROWS: list[tuple[McState, Input, McState]] = [
    *[(s, hlc(H.READY), M.STANDBY) for s in RESYNC],
    *[(s, hlc(H.GAINING_ALTITUDE), M.TAKEOFF) for s in RESYNC],
    *[(s, hlc(H.AIRBORNE), M.MISSION) for s in RESYNC],
    *[(s, hlc(H.RTL), M.RTL) for s in RESYNC],
    *[(s, hlc(H.LANDING), M.LAND) for s in RESYNC],
    *[(s, hlc(H.MANUAL), M.MANUAL) for s in RESYNC],
    *[(s, hlc(H.HOLD), M.HOLD) for s in RESYNC],
    (M.STANDBY, op(C.TAKEOFF), M.TAKEOFF),
    (M.TAKEOFF, hlc(H.AIRBORNE), M.MISSION),
    # "HLC back to READY after leaving it" is exercised separately (it needs two observations).
    (M.TAKEOFF, TIMEOUT, M.STANDBY),
    (M.TAKEOFF, hlc(H.LANDING), M.LAND),
    *[(s, op(C.LAND), M.LAND) for s in (M.TAKEOFF, M.MISSION, M.RTL, M.HOLD)],
    *[(s, op(C.RTL), M.RTL) for s in (M.TAKEOFF, M.MISSION, M.HOLD)],
    *[(s, hlc(H.LOW_BATTERY), M.RTL) for s in (M.TAKEOFF, M.MISSION, M.HOLD)],
    (M.RTL, hlc(H.LANDING), M.LAND),
    (M.HOLD, hlc(H.LANDING), M.LAND),
    *[(s, hlc(H.READY), M.STANDBY) for s in (M.RTL, M.LAND, M.HOLD)],
    *[(s, hlc(H.MANUAL), M.MANUAL) for s in (*FLYING_MC, M.HOLD)],
    (M.MANUAL, hlc(H.READY), M.STANDBY),
    *[(s, hlc(H.LLC_DOWN), M.ERROR) for s in McState if s is not M.ERROR],
    *[(s, SILENCE, M.HLC_LOST) for s in McState if s not in RESYNC],
    # the vehicle's own failsafes: follow it
    *[(s, hlc(H.HOLD), M.HOLD) for s in (*FLYING_MC, M.MANUAL)],
    *[(s, hlc(H.RTL), M.RTL) for s in (M.LAND, M.MANUAL, M.HOLD)],
    (M.MANUAL, hlc(H.LANDING), M.LAND),
    # the autopilot link is back (default policy: rtl)
    (M.ERROR, hlc(H.READY), M.STANDBY),
    (M.ERROR, hlc(H.RTL), M.RTL),
    (M.ERROR, hlc(H.LANDING), M.LAND),
    (M.ERROR, hlc(H.LOW_BATTERY), M.RTL),
    (M.ERROR, hlc(H.MANUAL), M.MANUAL),
    (M.ERROR, hlc(H.HOLD), M.RTL),
    (M.ERROR, hlc(H.AIRBORNE), M.RTL),
]

# Rows that need more than one input or another policy; each has a named test below.
SEQUENCE_ROWS: list[tuple[McState, Input, McState]] = [
    (M.TAKEOFF, hlc(H.READY), M.STANDBY),  # test_takeoff_cancelled_when_hlc_returns_to_ready_after_leaving_it
    (M.ERROR, op(C.RTL), M.RTL),  # test_error_accepts_rtl_and_land_once_the_hlc_reports_its_link_up
    (M.ERROR, op(C.LAND), M.LAND),
    *[(M.ERROR, hlc(h), target) for h in (H.HOLD, H.AIRBORNE) for target in (M.LAND, M.HOLD)],  # test_policy
]

# The rows the implementation adds (documented in antalate_lcm/agent/mc/machine.py).
EXTRA_ROWS: list[tuple[McState, Input, McState]] = [
    *[(s, hlc(H.LOW_BATTERY), M.RTL) for s in RESYNC],
    (M.TAKEOFF, hlc(H.RTL), M.RTL),
    (M.MISSION, hlc(H.RTL), M.RTL),
    (M.MISSION, hlc(H.LANDING), M.LAND),
    (M.MISSION, hlc(H.READY), M.STANDBY),
]


def _row_id(row: tuple[McState, Input, McState]) -> str:
    frm, (kind, value), to = row
    name = getattr(value, "name", "ack")
    return f"{frm.name}-{kind}_{name}-{to.name}"


# -------------------------------------------------------------------------------- the table


@pytest.mark.parametrize("row", DESIGN_ROWS + EXTRA_ROWS, ids=_row_id)
def test_row(row: tuple[McState, Input, McState]) -> None:
    frm, what, to = row
    mc = mc_in(frm)
    seq_before = mc.last_command_seq
    outcome = feed(mc, what)
    assert outcome.accepted, outcome.reason
    assert mc.state is to
    assert outcome.transition is not None
    assert (outcome.transition.from_state, outcome.transition.to_state) == (frm, to)
    assert outcome.reason == outcome.transition.reason and outcome.reason
    if what[0] == "op":
        assert mc.last_command_seq == 99
    else:
        assert mc.last_command_seq == seq_before  # a resync or observation sends/acks nothing


def test_every_hlc_observation_not_in_the_table_changes_nothing() -> None:
    expected = {(frm, what[1]): to for frm, what, to in DESIGN_ROWS + EXTRA_ROWS if what[0] == "hlc"}
    for frm in McState:
        for h in HlcState:
            mc = mc_in(frm)
            outcome = mc.on_hlc_state(h, T0 + 2)
            want = expected.get((frm, h), frm)
            if (frm, h) == (M.TAKEOFF, H.READY):
                want = M.TAKEOFF  # the HLC has not left READY yet: no cancellation
            assert mc.state is want, f"{frm.name} + HLC {h.name}"
            assert outcome.accepted
            assert (outcome.transition is None) == (want is frm)


def test_implementation_table_is_covered_by_the_expected_rows() -> None:
    """Every row of MC_TABLE corresponds to a DESIGN row or a documented extra, and vice versa."""
    listed = {(frm, what, to) for frm, what, to in DESIGN_ROWS + EXTRA_ROWS + SEQUENCE_ROWS}
    for row in MC_TABLE:
        if row.event is McEvent.TAKEOFF_ACK_TIMEOUT:
            what: Input = TIMEOUT
        elif row.event is McEvent.HLC_TIMEOUT:
            what = SILENCE
        elif row.event.name.startswith("OP_"):
            what = op(Command[row.event.name[3:]])
        else:
            what = hlc(HlcState[row.event.name[4:]])
        for frm in row.sources:
            assert (frm, what, row.target) in listed, row
            assert row.extra == ((frm, what, row.target) in EXTRA_ROWS), row


def test_takeoff_cancelled_when_hlc_returns_to_ready_after_leaving_it() -> None:
    mc = mc_in(M.TAKEOFF)
    assert mc.on_hlc_state(H.READY, T0 + 0.1).transition is None  # still the pre-command READY
    assert mc.on_hlc_state(H.TAKEOFF, T0 + 0.2).transition is None  # the HLC is arming
    outcome = mc.on_hlc_state(H.READY, T0 + 0.3)  # arming failed
    assert mc.state is M.STANDBY
    assert outcome.transition is not None and outcome.transition.event is McEvent.HLC_READY
    assert "takeoff failed" in outcome.reason


def test_resync_into_takeoff_then_hlc_ready_means_takeoff_failed() -> None:
    mc = mc_in(M.INIT)
    mc.on_hlc_state(H.GAINING_ALTITUDE, T0)
    assert mc.state is M.TAKEOFF
    mc.on_hlc_state(H.READY, T0 + 1)
    assert state_of(mc) is M.STANDBY


def test_error_waits_while_the_hlc_reports_llc_down() -> None:
    mc = mc_in(M.ERROR)
    for i in range(5):
        assert mc.on_hlc_state(H.LLC_DOWN, T0 + 1 + i * 0.2).transition is None
    for c in Command:
        outcome = mc.on_command(c, 50 + c, T0 + 2)
        assert not outcome.accepted and "ERROR" in outcome.reason
        if c is not C.TAKEOFF:
            assert "cannot be reached" in outcome.reason and "LLC_DOWN" in outcome.reason
    assert mc.tick(T0 + 2.5).transition is None
    assert mc.state is M.ERROR


def test_error_accepts_rtl_and_land_once_the_hlc_reports_its_link_up() -> None:
    """An HLC restarted during the outage and heard in INIT: not up yet; then up in a state with no row."""
    for command, target in ((C.RTL, M.RTL), (C.LAND, M.LAND)):
        mc = mc_in(M.ERROR)
        mc.on_hlc_state(H.INIT, T0 + 1)  # a restarted HLC: cannot execute anything yet
        assert not mc.on_command(command, 3, T0 + 1.1).accepted
        mc.on_hlc_state(H.TAKEOFF, T0 + 2)  # up (no ERROR row follows it)
        assert mc.state is M.ERROR
        outcome = mc.on_command(command, 4, T0 + 2.1)
        assert outcome.accepted and mc.state is target and mc.last_command_seq == 4


@pytest.mark.parametrize("policy, target", [("rtl", M.RTL), ("land", M.LAND), ("hold", M.HOLD)])
@pytest.mark.parametrize("hlc_state", [H.HOLD, H.AIRBORNE])
def test_policy(policy: str, target: McState, hlc_state: HlcState) -> None:
    mc = mc_in(M.ERROR, McParams(on_link_regained=policy))
    outcome = mc.on_hlc_state(hlc_state, T0 + 5)
    assert mc.state is target
    assert f"on_link_regained = {policy}" in outcome.reason and mc.reason == outcome.reason
    assert mc.last_command_seq == 0  # nothing acknowledged: the operator did not ask


def test_hold_by_policy_then_the_operators_land() -> None:
    mc = mc_in(M.ERROR, McParams(on_link_regained="hold"))
    mc.on_hlc_state(H.HOLD, T0 + 5)
    for i in range(3):
        assert mc.on_hlc_state(H.HOLD, T0 + 5.2 + i * 0.2).transition is None
    outcome = mc.on_command(C.LAND, 7, T0 + 6, sender="op")
    assert outcome.accepted and mc.state is M.LAND and mc.last_command_seq == 7
    assert mc.on_hlc_state(H.HOLD, T0 + 6.1).transition is None  # republished before the HLC heard LAND
    mc.on_hlc_state(H.LANDING, T0 + 6.3)
    assert mc.state is M.LAND


def test_a_republished_hlc_state_does_not_pull_the_mc_back() -> None:
    """MC RTL by policy on hearing HOLD; the HLC's next HOLD (sent before it heard RTL) changes nothing."""
    mc = mc_in(M.ERROR)
    mc.on_hlc_state(H.HOLD, T0 + 5)
    assert mc.state is M.RTL
    assert mc.on_hlc_state(H.HOLD, T0 + 5.2).transition is None
    assert mc.state is M.RTL
    mc = mc_in(M.RTL)
    mc.on_hlc_state(H.RTL, T0 + 2)
    mc.on_command(C.LAND, 5, T0 + 3, sender="op")
    assert mc.state is M.LAND
    assert mc.on_hlc_state(H.RTL, T0 + 3.1).transition is None  # not a new RTL of the vehicle's
    assert mc.state is M.LAND


def test_autopilot_failsafe_rtl_is_followed_and_the_operator_can_still_land() -> None:
    mc = mc_in(M.MISSION)
    outcome = mc.on_hlc_state(H.RTL, T0 + 5)
    assert mc.state is M.RTL and "on its own" in outcome.reason
    assert mc.on_command(C.LAND, 5, T0 + 6, sender="op").accepted
    assert state_of(mc) is M.LAND


def test_hlc_lost_after_the_timeout_and_resync_when_heard_again() -> None:
    mc = mc_in(M.MISSION, McParams(hlc_timeout=2.0))  # last HLC state heard at T0 + 0.3
    assert mc.tick(T0 + 2.2).transition is None
    outcome = mc.tick(T0 + 2.3)
    assert mc.state is M.HLC_LOST
    assert "HLC silent for 2.0 s; the vehicle is on its own GCS failsafe" in outcome.reason
    assert mc.reason == outcome.reason
    assert mc.tick(T0 + 10).transition is None  # reported once
    for c in Command:
        rejected = mc.on_command(c, 60 + c, T0 + 11, sender="op")
        assert not rejected.accepted and "nobody can execute it" in rejected.reason
    assert mc.on_hlc_state(H.INIT, T0 + 12).transition is None  # a new HLC, not synced yet
    outcome = mc.on_hlc_state(H.RTL, T0 + 13)
    assert state_of(mc) is M.RTL and "resync" in outcome.reason
    assert mc.last_command_seq == 1  # the resync acknowledged nothing


def test_no_hlc_lost_in_init() -> None:
    mc = MissionControl()
    assert mc.tick(T0 + 1e6).transition is None
    mc.on_hlc_state(H.INIT, T0)
    assert mc.tick(T0 + 1e6).transition is None
    assert mc.state is M.INIT


@pytest.mark.parametrize("value", ["", "RTL", "loiter"])
def test_link_regained_policy_validated(value: str) -> None:
    with pytest.raises(ValueError, match="on_link_regained"):
        McParams(on_link_regained=value)


def test_outcome_is_frozen() -> None:
    outcome = mc_in(M.INIT).on_hlc_state(H.READY, T0)
    with pytest.raises(FrozenInstanceError):
        outcome.accepted = False  # type: ignore[misc]


# -------------------------------------------------------------------------------- timeouts


def test_takeoff_ack_timeout_uses_the_injected_time() -> None:
    mc = mc_in(M.STANDBY, McParams(takeoff_ack_timeout=4.0))
    mc.on_command(C.TAKEOFF, 7, 50.0)
    assert mc.state is M.TAKEOFF
    assert mc.tick(53.99).transition is None
    mc.on_hlc_state(H.READY, 53.995)  # the HLC is still READY: no change
    outcome = mc.tick(54.0)
    assert state_of(mc) is M.STANDBY
    assert outcome.transition is not None and outcome.transition.event is McEvent.TAKEOFF_ACK_TIMEOUT
    assert "4 s" in outcome.reason
    assert mc.last_command_seq == 7  # the command was accepted; it just did not work


def test_no_ack_timeout_once_the_hlc_left_ready() -> None:
    mc = mc_in(M.STANDBY, McParams(takeoff_ack_timeout=4.0))
    mc.on_command(C.TAKEOFF, 7, 50.0)
    mc.on_hlc_state(H.TAKEOFF, 50.5)
    mc.on_hlc_state(H.GAINING_ALTITUDE, 51.0)
    mc.on_hlc_state(H.GAINING_ALTITUDE, 100.0)  # still climbing, still heard
    assert mc.tick(100.0).transition is None
    assert mc.state is M.TAKEOFF


def test_tick_outside_takeoff_does_nothing_while_the_hlc_is_heard() -> None:
    for s in McState:
        if s is not M.TAKEOFF:
            mc = mc_in(s)
            if mc.hlc_state is not None:
                mc.on_hlc_state(mc.hlc_state, T0 + 1e6)
            assert mc.tick(T0 + 1e6) == McOutcome(True)


# -------------------------------------------------------------------------------- commands


ACCEPTED = {
    C.TAKEOFF: {M.STANDBY},
    C.LAND: {M.TAKEOFF, M.MISSION, M.RTL, M.HOLD},
    C.RTL: {M.TAKEOFF, M.MISSION, M.HOLD},
}
REJECTIONS = [(s, c) for c in Command for s in McState if s not in ACCEPTED[c]]


@pytest.mark.parametrize("state, command", REJECTIONS, ids=lambda v: v.name)
def test_command_rejected_with_reason(state: McState, command: Command) -> None:
    mc = mc_in(state)
    seq_before = mc.last_command_seq
    outcome = mc.on_command(command, 42, T0 + 5, sender="console")
    assert not outcome.accepted
    assert outcome.transition is None
    assert mc.state is state
    assert mc.last_command_seq == seq_before
    assert command.name in outcome.reason and state.name in outcome.reason and "rejected" in outcome.reason
    for allowed in ACCEPTED[command]:
        assert allowed.name in outcome.reason  # tells the operator when it would work


def test_takeoff_altitude_is_recorded() -> None:
    mc = mc_in(M.STANDBY)
    assert mc.takeoff_altitude == 0.0
    outcome = mc.on_command(C.TAKEOFF, 3, T0, altitude=25.0)
    assert outcome.accepted and "25 m" in outcome.reason
    assert mc.takeoff_altitude == 25.0
    assert mc.last_command_seq == 3


@pytest.mark.parametrize("altitude", [float("nan"), float("inf"), -5.0])
def test_takeoff_with_invalid_altitude_rejected(altitude: float) -> None:
    mc = mc_in(M.STANDBY)
    outcome = mc.on_command(C.TAKEOFF, 3, T0, altitude=altitude)
    assert not outcome.accepted and "altitude" in outcome.reason
    assert mc.state is M.STANDBY and mc.last_command_seq == 0


def test_unknown_command_rejected() -> None:
    mc = mc_in(M.STANDBY)
    outcome = mc.on_command(17, 3, T0)
    assert not outcome.accepted and "unknown" in outcome.reason
    assert mc.last_command_seq == 0


def test_unknown_hlc_state_is_not_accepted() -> None:
    mc = mc_in(M.STANDBY)
    outcome = mc.on_hlc_state(42, T0)
    assert not outcome.accepted and "42" in outcome.reason
    assert mc.state is M.STANDBY


def test_plain_ints_from_the_wire_are_accepted() -> None:
    mc = MissionControl()
    mc.on_hlc_state(hlc_state_value := 1, T0)  # READY as it arrives in hlc_state_t.state
    assert hlc_state_value == H.READY and mc.state is M.STANDBY
    assert mc.on_command(operator_cmd_t.TAKEOFF, 1, T0).accepted
    assert state_of(mc) is M.TAKEOFF


# -------------------------------------------------------------------------------- duplicates


def test_duplicate_delivery_is_idempotent() -> None:
    mc = mc_in(M.STANDBY)
    first = mc.on_command(C.TAKEOFF, 5, T0, sender="console")
    assert first.accepted and first.transition is not None and not first.duplicate
    mc.on_hlc_state(H.TAKEOFF, T0 + 0.1)
    mc.on_hlc_state(H.AIRBORNE, T0 + 0.2)
    assert mc.state is M.MISSION
    again = mc.on_command(C.TAKEOFF, 5, T0 + 0.5, sender="console")  # resent before the ack arrived
    assert again.accepted and again.duplicate
    assert again.transition is None
    assert "duplicate" in again.reason
    assert mc.state is M.MISSION and mc.last_command_seq == 5


def test_duplicate_of_a_safety_command_does_not_retransition() -> None:
    mc = mc_in(M.MISSION)
    assert mc.on_command(C.LAND, 8, T0 + 3, sender="console").transition is not None
    assert mc.state is M.LAND
    for _ in range(3):
        outcome = mc.on_command(C.LAND, 8, T0 + 4, sender="console")
        assert outcome.duplicate and outcome.transition is None and outcome.accepted
    assert mc.state is M.LAND and mc.last_command_seq == 8


def test_same_seq_from_another_sender_is_a_new_command() -> None:
    mc = mc_in(M.MISSION)  # accepted TAKEOFF seq 1 from "op"
    outcome = mc.on_command(C.RTL, 1, T0 + 3, sender="auto_operator")
    assert outcome.accepted and not outcome.duplicate and mc.state is M.RTL


def test_same_seq_with_another_command_is_not_a_duplicate() -> None:
    mc = mc_in(M.STANDBY)
    mc.on_command(C.TAKEOFF, 4, T0, sender="op")
    outcome = mc.on_command(C.LAND, 4, T0 + 1, sender="op")
    assert outcome.accepted and not outcome.duplicate and mc.state is M.LAND


def test_duplicates_are_forgotten_after_the_window() -> None:
    """A restarted operator whose counter starts over is heard again after the window."""
    mc = mc_in(M.STANDBY, McParams(duplicate_window=10.0))
    mc.on_command(C.TAKEOFF, 1, 100.0, sender="op")
    mc.on_hlc_state(H.TAKEOFF, 100.5)
    mc.on_hlc_state(H.READY, 101.0)  # arming failed
    assert mc.state is M.STANDBY
    assert mc.on_command(C.TAKEOFF, 1, 105.0, sender="op").duplicate
    assert mc.state is M.STANDBY
    outcome = mc.on_command(C.TAKEOFF, 1, 111.0, sender="op")
    assert outcome.accepted and not outcome.duplicate and state_of(mc) is M.TAKEOFF


def test_rejected_command_redelivered_is_evaluated_again() -> None:
    mc = mc_in(M.INIT)
    assert not mc.on_command(C.TAKEOFF, 9, T0).accepted
    mc.on_hlc_state(H.READY, T0 + 1)
    outcome = mc.on_command(C.TAKEOFF, 9, T0 + 2)
    assert outcome.accepted and not outcome.duplicate and mc.last_command_seq == 9


@pytest.mark.parametrize("field", ["takeoff_ack_timeout", "duplicate_window", "hlc_timeout"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_params_validated(field: str, value: float) -> None:
    bad: dict[str, Any] = {field: value}
    with pytest.raises(ValueError, match=field):
        McParams(**bad)
