"""Mission Control state machine: every row of docs/design.md §5 (written out here independently of the
implementation's table), the documented extra rows, rejections, duplicates and the takeoff timeout."""

from __future__ import annotations

from dataclasses import FrozenInstanceError

import pytest

from antalate_lcm.hlc.machine import HlcState
from antalate_lcm.mc.machine import (
    MC_TABLE,
    McEvent,
    McOutcome,
    McParams,
    McState,
    MissionControl,
    OperatorCommand,
)
from antalate_lcm.msgs import mc_state_t, operator_cmd_t

M = McState
H = HlcState
C = OperatorCommand
T0 = 1000.0

# -------------------------------------------------------------------------------- helpers


def mc_in(state: McState, params: McParams | None = None) -> MissionControl:
    """An MC driven into `state` through legitimate inputs (so internal bookkeeping is realistic)."""
    mc = MissionControl(params)
    if state is M.INIT:
        return mc
    if state is M.ERROR:
        mc.on_hlc_state(H.LLC_DOWN, T0)
        assert mc.state is M.ERROR
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


Input = tuple[str, object]  # ("hlc", HlcState) | ("op", OperatorCommand) | ("timeout", None)


def feed(mc: MissionControl, what: Input, now: float = T0 + 2) -> McOutcome:
    kind, value = what
    if kind == "hlc":
        assert isinstance(value, HlcState)
        return mc.on_hlc_state(value, now)
    if kind == "op":
        assert isinstance(value, OperatorCommand)
        return mc.on_command(value, 99, now, sender="op")
    return mc.tick(now + 60.0)


def hlc(s: HlcState) -> Input:
    return ("hlc", s)


def op(c: OperatorCommand) -> Input:
    return ("op", c)


TIMEOUT: Input = ("timeout", None)
FLYING_MC = (M.TAKEOFF, M.MISSION, M.RTL, M.LAND)

# docs/design.md §5, row by row, expanded to (from, input, to).
DESIGN_ROWS: list[tuple[McState, Input, McState]] = [
    (M.INIT, hlc(H.READY), M.STANDBY),
    (M.INIT, hlc(H.GAINING_ALTITUDE), M.TAKEOFF),
    (M.INIT, hlc(H.AIRBORNE), M.MISSION),
    (M.INIT, hlc(H.RTL), M.RTL),
    (M.INIT, hlc(H.LANDING), M.LAND),
    (M.INIT, hlc(H.MANUAL), M.MANUAL),
    (M.STANDBY, op(C.TAKEOFF), M.TAKEOFF),
    (M.TAKEOFF, hlc(H.AIRBORNE), M.MISSION),
    # "HLC back to READY after leaving it" is exercised separately (it needs two observations).
    (M.TAKEOFF, TIMEOUT, M.STANDBY),
    (M.TAKEOFF, hlc(H.LANDING), M.LAND),
    (M.TAKEOFF, op(C.LAND), M.LAND),
    (M.MISSION, op(C.LAND), M.LAND),
    (M.TAKEOFF, op(C.RTL), M.RTL),
    (M.MISSION, op(C.RTL), M.RTL),
    (M.TAKEOFF, hlc(H.LOW_BATTERY), M.RTL),
    (M.MISSION, hlc(H.LOW_BATTERY), M.RTL),
    (M.RTL, hlc(H.LANDING), M.LAND),
    (M.RTL, hlc(H.READY), M.STANDBY),
    (M.LAND, hlc(H.READY), M.STANDBY),
    *[(s, hlc(H.MANUAL), M.MANUAL) for s in FLYING_MC],
    (M.MANUAL, hlc(H.READY), M.STANDBY),
    *[(s, hlc(H.LLC_DOWN), M.ERROR) for s in McState if s is not M.ERROR],
]

# The rows the implementation adds (documented in antalate_lcm/mc/machine.py).
EXTRA_ROWS: list[tuple[McState, Input, McState]] = [
    (M.INIT, hlc(H.LOW_BATTERY), M.RTL),
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


def test_state_values_match_the_lcm_constants() -> None:
    for s in McState:
        assert getattr(mc_state_t, s.name) == s.value
    for c in OperatorCommand:
        assert getattr(operator_cmd_t, c.name) == c.value


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
    listed = {(frm, what, to) for frm, what, to in DESIGN_ROWS + EXTRA_ROWS}
    listed.add((M.TAKEOFF, hlc(H.READY), M.STANDBY))
    for row in MC_TABLE:
        if row.event is McEvent.TAKEOFF_ACK_TIMEOUT:
            what: Input = TIMEOUT
        elif row.event.name.startswith("OP_"):
            what = op(OperatorCommand[row.event.name[3:]])
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
    assert mc.state is M.STANDBY


def test_error_is_terminal() -> None:
    mc = mc_in(M.ERROR)
    for h in HlcState:
        assert mc.on_hlc_state(h, T0 + 1).transition is None
    for c in OperatorCommand:
        outcome = mc.on_command(c, 50 + c, T0 + 1)
        assert not outcome.accepted and "ERROR" in outcome.reason
    assert mc.tick(T0 + 1e6).transition is None
    assert mc.state is M.ERROR


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
    assert mc.state is M.STANDBY
    assert outcome.transition is not None and outcome.transition.event is McEvent.TAKEOFF_ACK_TIMEOUT
    assert "4 s" in outcome.reason
    assert mc.last_command_seq == 7  # the command was accepted; it just did not work


def test_no_ack_timeout_once_the_hlc_left_ready() -> None:
    mc = mc_in(M.STANDBY, McParams(takeoff_ack_timeout=4.0))
    mc.on_command(C.TAKEOFF, 7, 50.0)
    mc.on_hlc_state(H.TAKEOFF, 50.5)
    mc.on_hlc_state(H.GAINING_ALTITUDE, 51.0)
    assert mc.tick(100.0).transition is None
    assert mc.state is M.TAKEOFF


def test_tick_outside_takeoff_does_nothing() -> None:
    for s in McState:
        if s is not M.TAKEOFF:
            mc = mc_in(s)
            assert mc.tick(T0 + 1e6) == McOutcome(True)


# -------------------------------------------------------------------------------- commands


ACCEPTED = {
    C.TAKEOFF: {M.STANDBY},
    C.LAND: {M.TAKEOFF, M.MISSION},
    C.RTL: {M.TAKEOFF, M.MISSION},
}
REJECTIONS = [(s, c) for c in OperatorCommand for s in McState if s not in ACCEPTED[c]]


@pytest.mark.parametrize("state, command", REJECTIONS, ids=lambda v: v.name)
def test_command_rejected_with_reason(state: McState, command: OperatorCommand) -> None:
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
    assert mc.state is M.TAKEOFF


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
    assert outcome.accepted and not outcome.duplicate and mc.state is M.TAKEOFF


def test_rejected_command_redelivered_is_evaluated_again() -> None:
    mc = mc_in(M.INIT)
    assert not mc.on_command(C.TAKEOFF, 9, T0).accepted
    mc.on_hlc_state(H.READY, T0 + 1)
    outcome = mc.on_command(C.TAKEOFF, 9, T0 + 2)
    assert outcome.accepted and not outcome.duplicate and mc.last_command_seq == 9


@pytest.mark.parametrize("field", ["takeoff_ack_timeout", "duplicate_window"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_params_validated(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        McParams(**{field: value})
