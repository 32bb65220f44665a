"""HLC state machine: every row of docs/design.md §6 (written out here), the documented extra rows, actions,
errors, edge/level triggering of MC states, timeouts with injected time, the failsafe rows (link
regained, autopilot failsafes, HOLD, battery by %/V/warning), and closed loops with the MC machine and
the simulator."""

from __future__ import annotations

from dataclasses import replace

import pytest

from antalate_lcm.agent.hlc.machine import (
    HLC_TABLE,
    Action,
    ActionKind,
    Control,
    ErrorCode,
    HighLevelControl,
    HlcEvent,
    HlcOutcome,
    HlcParams,
    classify,
    pilot_in_control,
)
from antalate_lcm.agent.mc.machine import MissionControl
from antalate_lcm.vehicles.base import FlightMode, Frame, VehicleState
from antalate_lcm.vehicles.sim import SimAdapter
from antalate_lcm.wire.vocabulary import Command, HlcState, McState, Severity
from tests.harness.clock import FakeClock

H = HlcState
M = McState
T0 = 500.0

GROUND = VehicleState(connected=True, link_age=0.1, lat=32.7, lon=35.0, battery=80.0, mode="GUIDED")
FLYING = replace(GROUND, armed=True, in_air=True, alt=10.0)


def flying(**changes: object) -> VehicleState:
    return replace(FLYING, **changes)  # type: ignore[arg-type]


def hlc_in(state: HlcState, params: HlcParams | None = None) -> HighLevelControl:
    """An HLC driven into `state` through legitimate inputs."""
    h = HighLevelControl(params)
    if state is H.INIT:
        h.on_mc_state(M.STANDBY, T0)  # the MC is heard; the autopilot not yet
        return h
    h.on_mc_state(M.STANDBY, T0)
    h.on_vehicle(GROUND, T0)
    assert h.state is H.READY
    if state is H.LLC_DOWN:
        h.on_vehicle(replace(GROUND, link_age=60.0), T0 + 1)
    elif state is not H.READY:
        h.on_mc_state(M.TAKEOFF, T0 + 1)
        if state is not H.TAKEOFF:
            h.on_action_result(ActionKind.ARM, True, T0 + 1)
            h.on_vehicle(flying(alt=1.0), T0 + 2)
            if state is not H.GAINING_ALTITUDE:
                h.on_vehicle(FLYING, T0 + 5)
                h.on_mc_state(M.MISSION, T0 + 5)
                if state is H.RTL:
                    h.on_mc_state(M.RTL, T0 + 6)
                elif state is H.LANDING:
                    h.on_mc_state(M.LAND, T0 + 6)
                elif state is H.LOW_BATTERY:
                    h.on_vehicle(flying(battery=15.0), T0 + 6)
                elif state is H.MANUAL:
                    h.on_vehicle(flying(autonomous=False, mode="LOITER"), T0 + 6)
                elif state is H.HOLD:
                    h.on_mc_state(M.HOLD, T0 + 6)
    assert h.state is state
    return h


# An input is one of: ("mc", McState), ("ap", VehicleState), ("arm", bool), ("tick", seconds later).
Input = tuple[str, object]


def state_of(h: HighLevelControl) -> HlcState:
    """The state read afresh: mypy keeps ``h.state`` narrowed by an earlier assert across the calls
    that change it."""
    return h.state


def feed(h: HighLevelControl, what: Input, now: float = T0 + 10) -> HlcOutcome:
    kind, value = what
    if kind == "mc":
        assert isinstance(value, McState)
        return h.on_mc_state(value, now)
    if kind == "ap":
        assert isinstance(value, VehicleState)
        return h.on_vehicle(value, now)
    if kind == "arm":
        assert isinstance(value, bool)
        return h.on_action_result(ActionKind.ARM, value, now)
    assert isinstance(value, float)
    return h.tick(now + value)


LANDED = replace(GROUND, mode="LAND")
TAKEN_OVER = flying(autonomous=False, mode="LOITER")
LOW = flying(battery=20.0)  # <= low_battery (20) counts
LOST = flying(link_age=3.0)
AUTONOMOUS = (H.GAINING_ALTITUDE, H.AIRBORNE, H.RTL, H.LANDING, H.LOW_BATTERY, H.HOLD)
FLYING_STATES = (*AUTONOMOUS, H.MANUAL)
AP_RTL = flying(mode="RTL", flight_mode=FlightMode.RTL)
AP_LAND = flying(mode="LAND", flight_mode=FlightMode.LANDING)
# Autopilot failsafes, reported the way a MAVLink adapter may: the vehicle left our control.
FS_RTL = flying(mode="RTL", flight_mode=FlightMode.RTL, autonomous=False, failsafe="fence breach")
FS_LAND = flying(mode="LAND", flight_mode=FlightMode.LANDING, autonomous=False, failsafe="EKF failsafe")
FS_HOLD = flying(mode="BRAKE", flight_mode=FlightMode.HOLD, autonomous=False, failsafe="fence breach")
PILOT_BRAKE = flying(mode="BRAKE", flight_mode=FlightMode.HOLD)  # no failsafe: a pilot's switch
LOW_VOLTS = flying(voltage=13.6, cells=4)  # 3.4 V per cell <= 3.5, battery % still 80
LOW_WARNING = flying(battery_warning="BATTERY_STATUS charge_state LOW")
NO_ERROR: tuple[ErrorCode, ...] = ()

# docs/design.md §6 row by row: (from, input, to, actions, error codes).
DESIGN_ROWS: list[tuple[HlcState, Input, HlcState, tuple[Action, ...], tuple[ErrorCode, ...]]] = [
    (H.READY, ("mc", M.TAKEOFF), H.TAKEOFF, (Action.ARM,), NO_ERROR),
    (H.TAKEOFF, ("arm", True), H.GAINING_ALTITUDE, (Action.takeoff(10.0),), NO_ERROR),
    (H.TAKEOFF, ("arm", False), H.READY, (), (ErrorCode.ARM_FAILED,)),
    (H.GAINING_ALTITUDE, ("ap", flying(alt=9.5)), H.AIRBORNE, (Action.HOVER,), NO_ERROR),
    (H.GAINING_ALTITUDE, ("tick", 30.0), H.LANDING, (Action.LAND,), (ErrorCode.GAIN_ALTITUDE_TIMEOUT,)),
    (H.AIRBORNE, ("mc", M.RTL), H.RTL, (Action.RTL,), NO_ERROR),
    (H.AIRBORNE, ("mc", M.LAND), H.LANDING, (Action.LAND,), NO_ERROR),
    *[(s, ("ap", LANDED), H.READY, (), NO_ERROR) for s in (H.RTL, H.LANDING, H.LOW_BATTERY, H.MANUAL)],
    *[(s, ("ap", TAKEN_OVER), H.MANUAL, (), (ErrorCode.PILOT_TAKEOVER,)) for s in AUTONOMOUS],
    *[
        (s, ("ap", LOW), H.LOW_BATTERY, (Action.RTL,), (ErrorCode.LOW_BATTERY,))
        for s in (H.GAINING_ALTITUDE, H.AIRBORNE)
    ],
    *[
        (s, ("ap", LOST), H.LLC_DOWN, (), (ErrorCode.LINK_LOST,))
        for s in HlcState
        if s not in (H.INIT, H.LLC_DOWN)
    ],
    # INIT (restart resync), with the MC heard
    (H.INIT, ("ap", GROUND), H.READY, (), NO_ERROR),
    (H.INIT, ("ap", FLYING), H.AIRBORNE, (), NO_ERROR),
    (H.INIT, ("ap", AP_LAND), H.LANDING, (), NO_ERROR),
    (H.INIT, ("ap", AP_RTL), H.RTL, (), NO_ERROR),
    (H.INIT, ("ap", TAKEN_OVER), H.MANUAL, (), NO_ERROR),
    (H.INIT, ("ap", FS_HOLD), H.HOLD, (), NO_ERROR),
    # LLC_DOWN is recoverable: the vehicle is re-read as it is
    (H.LLC_DOWN, ("ap", GROUND), H.READY, (), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", FLYING), H.HOLD, (Action.HOVER,), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", AP_RTL), H.RTL, (), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", FS_RTL), H.RTL, (), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", AP_LAND), H.LANDING, (), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", FS_HOLD), H.HOLD, (), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", TAKEN_OVER), H.MANUAL, (), (ErrorCode.LINK_REGAINED,)),
    (H.LLC_DOWN, ("ap", PILOT_BRAKE), H.MANUAL, (), (ErrorCode.LINK_REGAINED,)),
    # autopilot failsafes: follow the vehicle, never MANUAL
    *[
        (s, ("ap", FS_RTL), H.RTL, (), (ErrorCode.AUTOPILOT_FAILSAFE,))
        for s in FLYING_STATES
        if s not in (H.RTL, H.LOW_BATTERY)
    ],
    *[
        (s, ("ap", FS_LAND), H.LANDING, (), (ErrorCode.AUTOPILOT_FAILSAFE,))
        for s in FLYING_STATES
        if s is not H.LANDING
    ],
    *[
        (s, ("ap", FS_HOLD), H.HOLD, (), (ErrorCode.AUTOPILOT_FAILSAFE,))
        for s in FLYING_STATES
        if s is not H.HOLD
    ],
    # HOLD waits for the MC (an MC state new since HOLD began)
    (H.HOLD, ("mc", M.RTL), H.RTL, (Action.RTL,), NO_ERROR),
    (H.HOLD, ("mc", M.LAND), H.LANDING, (Action.LAND,), NO_ERROR),
    (H.AIRBORNE, ("mc", M.HOLD), H.HOLD, (Action.HOVER,), NO_ERROR),
    (H.HOLD, ("ap", AP_RTL), H.RTL, (), (ErrorCode.AUTOPILOT_TOOK_OVER,)),
    (H.HOLD, ("ap", AP_LAND), H.LANDING, (), (ErrorCode.AUTOPILOT_TOOK_OVER,)),
    # land now rather than fly home
    (H.RTL, ("mc", M.LAND), H.LANDING, (Action.LAND,), NO_ERROR),
    (H.LOW_BATTERY, ("mc", M.LAND), H.LANDING, (Action.LAND,), NO_ERROR),
    # low battery by volts per cell or by the vehicle's own warning, and in HOLD
    (H.AIRBORNE, ("ap", LOW_VOLTS), H.LOW_BATTERY, (Action.RTL,), (ErrorCode.LOW_BATTERY,)),
    (H.AIRBORNE, ("ap", LOW_WARNING), H.LOW_BATTERY, (Action.RTL,), (ErrorCode.LOW_BATTERY,)),
    (H.HOLD, ("ap", LOW), H.LOW_BATTERY, (Action.RTL,), (ErrorCode.LOW_BATTERY,)),
    (H.HOLD, ("ap", LANDED), H.READY, (), NO_ERROR),
]

EXTRA_ROWS: list[tuple[HlcState, Input, HlcState, tuple[Action, ...], tuple[ErrorCode, ...]]] = [
    (H.GAINING_ALTITUDE, ("mc", M.LAND), H.LANDING, (Action.LAND,), NO_ERROR),
    (H.GAINING_ALTITUDE, ("mc", M.RTL), H.RTL, (Action.RTL,), NO_ERROR),
    (H.AIRBORNE, ("ap", LANDED), H.READY, (), (ErrorCode.UNEXPECTED_LANDING,)),
    (
        H.AIRBORNE,
        ("ap", flying(mode="RTL", flight_mode=FlightMode.RTL)),
        H.RTL,
        (),
        (ErrorCode.AUTOPILOT_TOOK_OVER,),
    ),
    (
        H.GAINING_ALTITUDE,
        ("ap", flying(alt=3.0, mode="RTL", flight_mode=FlightMode.RTL)),
        H.RTL,
        (),
        (ErrorCode.AUTOPILOT_TOOK_OVER,),
    ),
    (
        H.AIRBORNE,
        ("ap", flying(mode="LAND", flight_mode=FlightMode.LANDING)),
        H.LANDING,
        (),
        (ErrorCode.AUTOPILOT_TOOK_OVER,),
    ),
    (H.RTL, ("ap", flying(mode="LAND", flight_mode=FlightMode.LANDING)), H.LANDING, (), NO_ERROR),
    (
        H.GAINING_ALTITUDE,
        ("ap", flying(alt=3.0, mode="LAND", flight_mode=FlightMode.LANDING)),
        H.LANDING,
        (),
        (ErrorCode.AUTOPILOT_TOOK_OVER,),
    ),
]


def _row_id(row: tuple[HlcState, Input, HlcState, tuple[Action, ...], tuple[ErrorCode, ...]]) -> str:
    frm, (kind, value), to, _, _ = row
    detail = getattr(value, "name", None) or (value.mode if isinstance(value, VehicleState) else value)
    if isinstance(value, VehicleState) and value.failsafe:
        detail = f"{detail}-failsafe"
    return f"{frm.name}-{kind}_{detail}-{to.name}"


def _fired(
    row: tuple[HlcState, Input, HlcState, tuple[Action, ...], tuple[ErrorCode, ...]],
) -> tuple[object, ...]:
    frm, what, to, _, _ = row
    outcome = feed(hlc_in(frm), what)
    assert outcome.transition is not None, _row_id(row)
    return (frm, outcome.transition.event, to)


@pytest.mark.parametrize("row", DESIGN_ROWS + EXTRA_ROWS, ids=_row_id)
def test_row(row: tuple[HlcState, Input, HlcState, tuple[Action, ...], tuple[ErrorCode, ...]]) -> None:
    frm, what, to, actions, codes = row
    h = hlc_in(frm)
    outcome = feed(h, what)
    assert h.state is to, outcome.reason
    assert outcome.transition is not None
    assert (outcome.transition.from_state, outcome.transition.to_state) == (frm, to)
    assert outcome.actions == actions
    assert tuple(e.code for e in outcome.errors) == codes
    assert outcome.reason and outcome.transition.reason == outcome.reason
    for error in outcome.errors:
        assert error.text


def test_every_table_row_is_a_listed_row() -> None:
    """Each (source, event, target) of HLC_TABLE is exercised by a DESIGN or EXTRA row above (or, for the
    three rows that need a sequence of inputs, by a named test below), and flagged extra only if EXTRA."""
    design = {_fired(row) for row in DESIGN_ROWS}
    extra = {_fired(row) for row in EXTRA_ROWS}
    elsewhere = {
        (H.TAKEOFF, HlcEvent.ARMED, H.READY),  # test_takeoff_cancelled_while_arming
        (H.GAINING_ALTITUDE, HlcEvent.TAKEOFF_FAILED, H.LANDING),  # test_a_refused_takeoff_lands_at_once
    }
    for row in HLC_TABLE:
        if row.target is None:
            continue  # refusals: test_takeoff_refused_on_low_battery_stays_ready_with_error
        for frm in row.sources:
            key = (frm, row.event, row.target)
            if key in elsewhere:
                continue
            assert key in (extra if row.extra else design), row


def test_extra_rows_are_flagged_in_the_table() -> None:
    extra_events = {row.event for row in HLC_TABLE if row.extra}
    assert extra_events == {
        HlcEvent.MC_LAND,
        HlcEvent.MC_RTL,
        HlcEvent.ARMED,
        HlcEvent.LANDED,
        HlcEvent.AUTOPILOT_LAND,
        HlcEvent.AUTOPILOT_RTL,
        HlcEvent.TAKEOFF_FAILED,
    }


def test_a_refused_takeoff_lands_at_once() -> None:
    """A vehicle with no arming step (a Tello) refuses at takeoff: land now, not after the timeout."""
    h = HighLevelControl()
    h.on_mc_state(M.STANDBY, T0)
    h.on_vehicle(GROUND, T0)
    h.on_mc_state(M.TAKEOFF, T0 + 1)
    h.on_action_result(ActionKind.ARM, True, T0 + 1.1)
    assert h.state is H.GAINING_ALTITUDE
    outcome = h.on_action_result(ActionKind.TAKEOFF, False, T0 + 1.2, "error")
    assert state_of(h) is H.LANDING
    assert Action.LAND in outcome.actions
    assert [e.code for e in outcome.errors] == [ErrorCode.TAKEOFF_REFUSED]
    assert h.on_vehicle(GROUND, T0 + 1.3).transition is not None
    assert state_of(h) is H.READY


# -------------------------------------------------------------------------------- INIT


def test_init_to_ready_needs_both_autopilot_and_mc() -> None:
    h = HighLevelControl()
    assert h.on_vehicle(GROUND, T0).transition is None  # no MC yet
    assert h.state is H.INIT
    outcome = h.on_mc_state(M.STANDBY, T0 + 1)  # the MC arrives second
    assert state_of(h) is H.READY and outcome.actions == ()

    h = HighLevelControl()
    assert h.on_mc_state(M.INIT, T0).transition is None  # no autopilot yet
    assert h.on_vehicle(GROUND, T0 + 1).transition is not None
    assert h.state is H.READY


@pytest.mark.parametrize(
    "snapshot",
    [replace(GROUND, connected=False), replace(GROUND, link_age=3.0), VehicleState()],
    ids=["not-connected", "stale", "nothing-known"],
)
def test_init_waits_for_a_fresh_link_and_never_declares_llc_down(snapshot: VehicleState) -> None:
    h = HighLevelControl()
    h.on_mc_state(M.STANDBY, T0)
    for i in range(5):
        assert h.on_vehicle(replace(snapshot, link_age=snapshot.link_age + i), T0 + i).transition is None
    assert h.state is H.INIT


@pytest.mark.parametrize(
    "snapshot, expected",
    [
        (flying(mode="GUIDED"), H.AIRBORNE),
        (flying(mode="LAND", flight_mode=FlightMode.LANDING), H.LANDING),
        (flying(mode="RTL", flight_mode=FlightMode.RTL), H.RTL),
        (flying(mode="LOITER", autonomous=False), H.MANUAL),
        (flying(mode="POSHOLD", flight_mode=FlightMode.MANUAL), H.MANUAL),
    ],
    ids=lambda v: getattr(v, "mode", None) or v.name,
)
def test_init_resync_from_a_flying_vehicle(snapshot: VehicleState, expected: HlcState) -> None:
    h = HighLevelControl()
    h.on_mc_state(M.MISSION, T0)
    outcome = h.on_vehicle(snapshot, T0)
    assert h.state is expected
    assert outcome.actions == ()  # a resync commands nothing
    assert outcome.transition is not None and "resync" in outcome.reason


def test_init_armed_on_the_ground_is_ready() -> None:
    h = HighLevelControl()
    h.on_mc_state(M.STANDBY, T0)
    h.on_vehicle(replace(GROUND, armed=True), T0)
    assert h.state is H.READY


# -------------------------------------------------------------------------------- takeoff


def test_takeoff_refused_on_low_battery_stays_ready_with_error() -> None:
    h = hlc_in(H.READY)
    h.on_vehicle(replace(GROUND, battery=20.0), T0 + 1)
    outcome = h.on_mc_state(M.TAKEOFF, T0 + 2)
    assert h.state is H.READY
    assert outcome.transition is None and outcome.actions == ()
    assert [(e.code, e.severity) for e in outcome.errors] == [
        (ErrorCode.TAKEOFF_REFUSED_LOW_BATTERY, Severity.ERROR)
    ]
    assert "20" in outcome.errors[0].text
    # The MC republishes TAKEOFF: no second refusal (edge-triggered), no arming.
    assert h.on_mc_state(M.TAKEOFF, T0 + 2.2) == HlcOutcome()


def test_unknown_battery_is_never_low() -> None:
    h = hlc_in(H.READY)
    h.on_vehicle(replace(GROUND, battery=-1.0), T0 + 1)
    assert h.on_mc_state(M.TAKEOFF, T0 + 2).actions == (Action.ARM,)
    h = hlc_in(H.AIRBORNE)
    assert h.on_vehicle(flying(battery=-1.0), T0 + 20).transition is None


def test_requested_takeoff_altitude_is_used_and_latched() -> None:
    h = hlc_in(H.READY)
    h.on_mc_state(M.TAKEOFF, T0 + 1, takeoff_altitude=25.0)
    outcome = h.on_action_result(ActionKind.ARM, True, T0 + 2)
    assert outcome.actions == (Action.takeoff(25.0),)
    assert h.target_altitude == 25.0
    h.on_mc_state(M.TAKEOFF, T0 + 2.2, takeoff_altitude=50.0)  # a later request does not move the goal
    assert h.on_vehicle(flying(alt=23.0), T0 + 9).transition is None
    assert h.on_vehicle(flying(alt=23.75), T0 + 10).transition is not None  # 0.95 x 25
    assert h.state is H.AIRBORNE


def test_zero_altitude_means_the_default() -> None:
    h = hlc_in(H.READY, HlcParams(default_takeoff_altitude=7.0))
    h.on_mc_state(M.TAKEOFF, T0 + 1, takeoff_altitude=0.0)
    assert h.on_action_result(ActionKind.ARM, True, T0 + 2).actions == (Action.takeoff(7.0),)


def test_altitude_threshold_is_the_airborne_fraction() -> None:
    h = hlc_in(H.GAINING_ALTITUDE)
    assert h.on_vehicle(flying(alt=9.49), T0 + 3).transition is None
    assert h.on_vehicle(flying(alt=9.5), T0 + 4).transition is not None


def test_failed_arm_does_not_rearm_on_mc_republish_but_on_the_next_command() -> None:
    h = hlc_in(H.TAKEOFF)
    h.on_action_result(ActionKind.ARM, False, T0 + 2, "pre-arm: compass")
    assert h.state is H.READY
    for i in range(5):  # the MC still says TAKEOFF until it sees READY
        assert h.on_mc_state(M.TAKEOFF, T0 + 2.2 + i * 0.2) == HlcOutcome()
    h.on_mc_state(M.STANDBY, T0 + 4)
    assert h.on_mc_state(M.TAKEOFF, T0 + 5).actions == (Action.ARM,)
    assert state_of(h) is H.TAKEOFF


def test_arm_failure_detail_reaches_the_error_text() -> None:
    h = hlc_in(H.TAKEOFF)
    outcome = h.on_action_result(ActionKind.ARM, False, T0 + 2, "pre-arm: compass")
    assert outcome.errors[0].severity is Severity.ERROR
    assert "compass" in outcome.errors[0].text


def test_hlc_started_while_mc_already_in_takeoff_does_not_take_off() -> None:
    h = HighLevelControl()
    h.on_vehicle(GROUND, T0)
    h.on_mc_state(M.TAKEOFF, T0)
    assert h.state is H.READY
    assert h.on_mc_state(M.TAKEOFF, T0 + 0.2) == HlcOutcome()
    assert h.state is H.READY


def test_takeoff_cancelled_while_arming() -> None:
    h = hlc_in(H.TAKEOFF)
    h.on_mc_state(M.LAND, T0 + 1.5)  # the operator changed their mind before the arm result
    assert h.state is H.TAKEOFF
    outcome = h.on_action_result(ActionKind.ARM, True, T0 + 2)
    assert state_of(h) is H.READY
    assert outcome.actions == (Action.DISARM,)
    assert [(e.code, e.severity) for e in outcome.errors] == [(ErrorCode.TAKEOFF_CANCELLED, Severity.INFO)]


def test_gain_altitude_timeout_counts_from_entering_the_state() -> None:
    h = hlc_in(H.GAINING_ALTITUDE, HlcParams(gain_altitude_timeout=12.0))  # entered at T0 + 1
    assert h.tick(T0 + 12.9).transition is None
    outcome = h.tick(T0 + 13.0)
    assert h.state is H.LANDING and outcome.actions == (Action.LAND,)
    assert outcome.errors[0].severity is Severity.WARNING


def test_tick_does_nothing_in_other_states() -> None:
    for s in HlcState:
        if s is not H.GAINING_ALTITUDE:
            assert hlc_in(s).tick(T0 + 1e6) == HlcOutcome()


# -------------------------------------------------------------------------------- flight


def test_low_battery_fires_once() -> None:
    h = hlc_in(H.AIRBORNE)
    first = h.on_vehicle(flying(battery=19.0), T0 + 20)
    assert first.actions == (Action.RTL,)
    for i in range(10):
        again = h.on_vehicle(flying(battery=18.0 - i), T0 + 21 + i)
        assert again == HlcOutcome()
    assert h.state is H.LOW_BATTERY


def test_a_battery_failsafe_hold_after_low_battery_stays_hold_instead_of_alternating() -> None:
    """PX4 1.15.4 SITL: the HLC's LOW_BATTERY RTL, then PX4's battery failsafe holds COM_FAIL_ACT_T
    (5 s) before its action; HOLD's low-battery row fired again, FAILSAFE_HOLD again, ... dozens of
    transitions and RTL commands a second. Now: LOW_BATTERY once, then HOLD until PX4 acts."""
    h = hlc_in(H.AIRBORNE)
    assert h.on_vehicle(flying(battery=19.0), T0 + 20).actions == (Action.RTL,)
    held = flying(battery=15.0, flight_mode=FlightMode.HOLD, mode="AUTO.LOITER", failsafe="battery failsafe")
    assert h.on_vehicle(held, T0 + 21).transition is not None
    assert h.state is H.HOLD
    for i in range(10):
        assert h.on_vehicle(held, T0 + 21.05 + 0.05 * i).transition is None
    assert h.state is H.HOLD
    landing = replace(held, flight_mode=FlightMode.LANDING, mode="AUTO.LAND")
    assert h.on_vehicle(landing, T0 + 27).transition is not None
    assert state_of(h) is H.LANDING


def test_a_fence_hold_with_a_low_battery_still_returns_once() -> None:
    h = hlc_in(H.AIRBORNE)
    held = flying(flight_mode=FlightMode.HOLD, mode="BRAKE", failsafe="fence breach")
    h.on_vehicle(held, T0 + 20)
    assert h.state is H.HOLD
    assert h.on_vehicle(replace(held, battery=19.0), T0 + 21).actions == (Action.RTL,)
    assert state_of(h) is H.LOW_BATTERY


@pytest.mark.parametrize("state", [H.RTL, H.LANDING, H.MANUAL, H.READY, H.TAKEOFF])
def test_low_battery_does_not_reroute_a_vehicle_already_coming_down(state: HlcState) -> None:
    h = hlc_in(state)
    snapshot = flying(battery=5.0, mode=h.vehicle.mode if h.vehicle else "")
    if state is H.MANUAL:
        snapshot = replace(snapshot, autonomous=False, flight_mode=FlightMode.MANUAL)
    if state in (H.READY, H.TAKEOFF):
        snapshot = replace(GROUND, battery=5.0)
    assert h.on_vehicle(snapshot, T0 + 30).transition is None
    assert h.state is state


def test_mc_land_and_rtl_are_level_triggered() -> None:
    """A LAND first heard while the HLC could not act is honoured in the next state."""
    h = hlc_in(H.GAINING_ALTITUDE)
    h.on_mc_state(M.TAKEOFF, T0 + 2)
    h.on_vehicle(FLYING, T0 + 3)
    assert h.state is H.AIRBORNE
    assert h.on_mc_state(M.LAND, T0 + 4).actions == (Action.LAND,)
    assert h.on_mc_state(M.LAND, T0 + 4.2) == HlcOutcome()  # already LANDING: no repeat


@pytest.mark.parametrize("state", [H.READY, H.TAKEOFF, H.MANUAL])
def test_mc_land_ignored_where_no_row(state: HlcState) -> None:
    h = hlc_in(state)
    assert h.on_mc_state(M.LAND, T0 + 30).transition is None
    assert h.state is state


@pytest.mark.parametrize("mc_state", [M.RTL, M.LAND])
def test_an_mc_state_republished_since_before_a_failsafe_does_not_override_it(mc_state: McState) -> None:
    """The MC republishes RTL at 5 Hz; one sent before it heard the fence BRAKE must not undo the BRAKE."""
    h = hlc_in(H.AIRBORNE)
    h.on_mc_state(mc_state, T0 + 10)
    assert h.state in (H.RTL, H.LANDING)
    assert h.on_vehicle(FS_HOLD, T0 + 11).transition is not None
    assert state_of(h) is H.HOLD
    for i in range(5):
        assert h.on_mc_state(mc_state, T0 + 11.1 + i * 0.2) == HlcOutcome()
    assert state_of(h) is H.HOLD
    h.on_mc_state(M.HOLD, T0 + 12)  # the MC follows the vehicle
    outcome = h.on_mc_state(M.RTL, T0 + 13)  # the operator's RTL: new since HOLD began
    assert h.state is H.RTL and outcome.actions == (Action.RTL,)


def test_a_failsafe_rtl_then_the_operators_land() -> None:
    h = hlc_in(H.AIRBORNE)
    outcome = h.on_vehicle(FS_RTL, T0 + 10)
    assert h.state is H.RTL
    assert [(e.code, e.severity) for e in outcome.errors] == [
        (ErrorCode.AUTOPILOT_FAILSAFE, Severity.WARNING)
    ]
    assert "fence breach" in outcome.errors[0].text and "fence breach" in h.reason
    assert h.on_mc_state(M.MISSION, T0 + 10.1) == HlcOutcome()  # republished before the MC heard
    assert h.on_mc_state(M.RTL, T0 + 10.3) == HlcOutcome()  # the MC follows
    assert h.on_mc_state(M.LAND, T0 + 11).actions == (Action.LAND,)
    assert state_of(h) is H.LANDING


def test_no_takeover_without_armed_vehicle_or_in_takeoff() -> None:
    h = hlc_in(H.GAINING_ALTITUDE)
    # A stale snapshot from before arming (disarmed, pilot mode) is not a takeover.
    stale = replace(GROUND, mode="STABILIZE", autonomous=False, armed=True, in_air=False)
    assert h.on_vehicle(replace(stale, armed=False), T0 + 2).transition is None
    h = hlc_in(H.TAKEOFF)
    assert h.on_vehicle(stale, T0 + 2).transition is None
    assert h.state is H.TAKEOFF


def test_landed_in_manual_returns_to_ready_even_in_a_pilot_mode() -> None:
    h = hlc_in(H.MANUAL)
    outcome = h.on_vehicle(replace(GROUND, mode="LOITER", autonomous=False), T0 + 30)
    assert h.state is H.READY and outcome.errors == ()


def test_llc_down_waits_while_the_link_is_stale_and_commands_nothing() -> None:
    h = hlc_in(H.AIRBORNE)
    outcome = h.on_vehicle(LOST, T0 + 20)
    assert h.state is H.LLC_DOWN
    assert outcome.errors[0].severity is Severity.CRITICAL and "3.0 s" in outcome.errors[0].text
    for age in (3.0, 10.0, float("inf")):
        assert h.on_vehicle(flying(link_age=age), T0 + 30) == HlcOutcome()
    assert h.on_vehicle(replace(FLYING, connected=False), T0 + 30) == HlcOutcome()
    for mc_state in McState:
        assert h.on_mc_state(mc_state, T0 + 31) == HlcOutcome()
    assert h.on_action_result(ActionKind.ARM, True, T0 + 32) == HlcOutcome()
    assert h.tick(T0 + 1e6) == HlcOutcome()
    assert h.state is H.LLC_DOWN


def test_link_regained_in_guided_holds_then_follows_the_mc() -> None:
    h = hlc_in(H.AIRBORNE)
    h.on_vehicle(LOST, T0 + 20)
    outcome = h.on_vehicle(flying(link_age=0.2), T0 + 25)
    assert h.state is H.HOLD and outcome.actions == (Action.HOVER,)
    assert outcome.errors[0].severity is Severity.WARNING and "GUIDED" in outcome.errors[0].text
    assert "link regained" in h.reason
    assert h.on_mc_state(M.ERROR, T0 + 25.1) == HlcOutcome()  # the MC has not decided yet
    assert h.on_mc_state(M.RTL, T0 + 25.3).actions == (Action.RTL,)  # its on_link_regained policy
    assert state_of(h) is H.RTL


def test_state_raising_is_a_stale_link_with_the_fault_as_reason() -> None:
    h = hlc_in(H.AIRBORNE)
    fault = "autopilot sim state() raised RuntimeError: boom"
    assert h.on_vehicle(flying(link_age=1.0), T0 + 20, fault=fault).transition is None
    outcome = h.on_vehicle(flying(link_age=3.1), T0 + 22, fault=fault)
    assert h.state is H.LLC_DOWN
    assert "boom" in outcome.reason and "boom" in outcome.errors[0].text and "boom" in h.reason


def test_reason_is_the_last_transitions() -> None:
    h = HighLevelControl()
    assert h.reason  # says what INIT waits for
    h.on_mc_state(M.STANDBY, T0)
    outcome = h.on_vehicle(GROUND, T0)
    assert h.reason == outcome.reason and "connected" in h.reason
    h.on_mc_state(M.TAKEOFF, T0 + 1)
    assert "arming" in h.reason


def test_link_timeout_is_a_parameter() -> None:
    h = hlc_in(H.AIRBORNE, HlcParams(link_timeout=1.0))
    assert h.on_vehicle(flying(link_age=0.99), T0 + 20).transition is None
    assert h.on_vehicle(flying(link_age=1.0), T0 + 21).transition is not None


def test_failed_non_arm_action_reports_an_error_only() -> None:
    h = hlc_in(H.LANDING)
    outcome = h.on_action_result(ActionKind.LAND, False, T0 + 20, "no ACK")
    assert outcome.transition is None and h.state is H.LANDING
    assert [(e.code, e.severity) for e in outcome.errors] == [(ErrorCode.ACTION_FAILED, Severity.ERROR)]
    assert "LAND" in outcome.errors[0].text and "no ACK" in outcome.errors[0].text
    assert h.on_action_result(ActionKind.LAND, True, T0 + 21) == HlcOutcome()


def test_action_helpers() -> None:
    assert Action.takeoff(12.0) == Action(ActionKind.TAKEOFF, 12.0)
    assert str(Action.takeoff(12.0)) == "TAKEOFF(12 m)"
    assert str(Action.HOVER) == "HOVER"
    assert {Action.ARM.kind, Action.DISARM.kind, Action.LAND.kind, Action.RTL.kind} == {
        ActionKind.ARM,
        ActionKind.DISARM,
        ActionKind.LAND,
        ActionKind.RTL,
    }


@pytest.mark.parametrize(
    "changes",
    [
        {"default_takeoff_altitude": 0.0},
        {"airborne_fraction": 0.0},
        {"airborne_fraction": 1.5},
        {"gain_altitude_timeout": -1.0},
        {"low_battery": 100.0},
        {"link_timeout": float("nan")},
    ],
)
def test_params_validated(changes: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        HlcParams(**changes)


# -------------------------------------------------------------------------------- closed loop


class Loop:
    """A minimal stand-in for the MC and HLC nodes: wires the two machines and a sim by hand."""

    def __init__(self, sim_params: dict[str, object] | None = None) -> None:
        self.clock = FakeClock(10.0)
        self.sim = SimAdapter(sim_params or {}, clock=self.clock)
        self.sim.connect()
        self.mc = MissionControl()
        self.hlc = HighLevelControl()
        self.hlc_log: list[tuple[HlcState, HlcState]] = []
        self.mc_log: list[tuple[McState, McState]] = []
        self.errors: list[ErrorCode] = []

    def _hlc(self, outcome: HlcOutcome) -> None:
        if outcome.transition:
            self.hlc_log.append((outcome.transition.from_state, outcome.transition.to_state))
            # The node publishes hlc_state_t on every change, so the MC hears every state.
            self._mc(self.mc.on_hlc_state(outcome.transition.to_state, self.clock.t))
        self.errors.extend(e.code for e in outcome.errors)
        for action in outcome.actions:
            if action.kind is ActionKind.ARM:
                self._hlc(self.hlc.on_action_result(ActionKind.ARM, self.sim.arm(), self.clock.t))
            elif action.kind is ActionKind.TAKEOFF:
                self.sim.takeoff(action.altitude)
            elif action.kind is ActionKind.LAND:
                self.sim.land()
            elif action.kind is ActionKind.RTL:
                self.sim.rtl()
            elif action.kind is ActionKind.DISARM:
                self.sim.disarm()
            else:
                self.sim.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.BODY)

    def _mc(self, outcome: object) -> None:
        transition = getattr(outcome, "transition", None)
        if transition:
            self.mc_log.append((transition.from_state, transition.to_state))

    def command(self, command: Command, seq: int, altitude: float = 0.0) -> None:
        outcome = self.mc.on_command(command, seq, self.clock.t, altitude=altitude)
        assert outcome.accepted, outcome.reason
        self._mc(outcome)

    def run(self, seconds: float, dt: float = 0.1) -> None:
        for _ in range(round(seconds / dt)):
            now = self.clock.t
            self._mc(self.mc.on_hlc_state(self.hlc.state, now))
            self._mc(self.mc.tick(now))
            self._hlc(self.hlc.on_mc_state(self.mc.state, now, takeoff_altitude=self.mc.takeoff_altitude))
            self._hlc(self.hlc.on_vehicle(self.sim.state(), now))
            self._hlc(self.hlc.tick(now))
            self.clock.t += dt


def test_closed_loop_takeoff_mission_rtl() -> None:
    loop = Loop()
    loop.run(1.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    loop.command(Command.TAKEOFF, 1, altitude=15.0)
    loop.run(10.0)
    assert (loop.mc.state, loop.hlc.state) == (M.MISSION, H.AIRBORNE)
    assert loop.sim.state().alt == pytest.approx(15.0, abs=0.01)
    loop.sim.set_velocity(5.0, 0.0, 0.0, 0.0, Frame.NED)
    loop.run(2.0)
    loop.command(Command.RTL, 2)
    loop.run(30.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    assert loop.hlc_log == [
        (H.INIT, H.READY),
        (H.READY, H.TAKEOFF),
        (H.TAKEOFF, H.GAINING_ALTITUDE),
        (H.GAINING_ALTITUDE, H.AIRBORNE),
        (H.AIRBORNE, H.RTL),
        (H.RTL, H.READY),
    ]
    assert loop.mc_log == [
        (M.INIT, M.STANDBY),
        (M.STANDBY, M.TAKEOFF),
        (M.TAKEOFF, M.MISSION),
        (M.MISSION, M.RTL),
        (M.RTL, M.STANDBY),
    ]
    assert loop.sim.state().landed and loop.errors == []


def test_closed_loop_arm_refused_returns_everyone_to_standby() -> None:
    loop = Loop({"refuse_arm": True})
    loop.run(1.0)
    loop.command(Command.TAKEOFF, 1)
    loop.run(2.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    assert loop.errors == [ErrorCode.ARM_FAILED]
    assert loop.mc_log[-2:] == [(M.STANDBY, M.TAKEOFF), (M.TAKEOFF, M.STANDBY)]


def test_closed_loop_pilot_takeover_and_link_loss() -> None:
    loop = Loop({"takeover_land_delay": 1.0})
    loop.run(1.0)
    loop.command(Command.TAKEOFF, 1)
    loop.run(6.0)
    loop.sim.pilot_takeover()
    loop.run(0.5)
    assert (loop.mc.state, loop.hlc.state) == (M.MANUAL, H.MANUAL)
    loop.run(10.0)  # the pilot lands and disarms
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    loop.sim.set_link_loss(True)
    loop.run(4.0)
    assert (loop.mc.state, loop.hlc.state) == (M.ERROR, H.LLC_DOWN)
    assert loop.errors == [ErrorCode.PILOT_TAKEOVER, ErrorCode.LINK_LOST]


def test_closed_loop_low_battery_brings_it_home() -> None:
    loop = Loop({"battery": 25.0, "drain_flying": 30.0})  # 0.5 %/s: low after ~10 s in the air
    loop.run(1.0)
    loop.command(Command.TAKEOFF, 1)
    loop.run(9.0)
    assert (loop.mc.state, loop.hlc.state) == (M.MISSION, H.AIRBORNE)
    loop.run(2.0)
    assert (loop.mc.state, loop.hlc.state) == (M.RTL, H.LOW_BATTERY)
    assert loop.sim.state().mode == "RTL"
    loop.run(10.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    assert loop.hlc_log[-2:] == [(H.AIRBORNE, H.LOW_BATTERY), (H.LOW_BATTERY, H.READY)]
    assert loop.errors == [ErrorCode.LOW_BATTERY]


def test_closed_loop_restarts_resync_without_commands() -> None:
    loop = Loop()
    loop.run(1.0)
    loop.command(Command.TAKEOFF, 1)
    loop.run(6.0)
    assert (loop.mc.state, loop.hlc.state) == (M.MISSION, H.AIRBORNE)
    loop.sim.rtl()  # e.g. the autopilot's own failsafe
    loop.run(0.3)
    assert (loop.mc.state, loop.hlc.state) == (M.RTL, H.RTL)
    loop.mc, loop.hlc = MissionControl(), HighLevelControl()  # both processes restart mid-flight
    loop.hlc_log.clear()
    loop.run(0.5)
    assert (loop.mc.state, loop.hlc.state) == (M.RTL, H.RTL)
    assert loop.hlc_log == [(H.INIT, H.RTL)]
    assert loop.sim.state().in_air  # nothing was commanded: still flying its RTL
    loop.run(15.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)


# -------------------------------------------------------------------------------- failsafes


@pytest.mark.parametrize(
    "snapshot, pilot",
    [
        (FLYING, False),
        (TAKEN_OVER, True),
        (flying(flight_mode=FlightMode.MANUAL), True),
        (PILOT_BRAKE, True),  # HOLD without a failsafe: a pilot's BRAKE
        (FS_HOLD, False),
        (FS_RTL, False),
        (FS_LAND, False),
        (
            flying(
                mode="LOITER", autonomous=False, failsafe="battery failsafe", flight_mode=FlightMode.MANUAL
            ),
            True,
        ),
        (flying(mode="RTL", flight_mode=FlightMode.RTL, autonomous=False), True),  # a pilot's RTL switch
    ],
    ids=lambda v: v if isinstance(v, bool) else f"{v.mode}-{v.flight_mode.name}-{v.failsafe or 'nofs'}",
)
def test_pilot_is_only_a_real_pilot(snapshot: VehicleState, pilot: bool) -> None:
    assert pilot_in_control(snapshot) is pilot


def test_classify() -> None:
    assert classify(GROUND) is Control.GROUND
    assert classify(replace(GROUND, armed=True)) is Control.GROUND
    assert classify(FLYING) is Control.GUIDED
    assert classify(FS_RTL) is Control.RTL and classify(AP_RTL) is Control.RTL
    assert classify(FS_LAND) is Control.LANDING
    assert classify(FS_HOLD) is Control.HOLD
    assert classify(PILOT_BRAKE) is Control.PILOT and classify(TAKEN_OVER) is Control.PILOT


@pytest.mark.parametrize(
    "snapshot, words",
    [
        (flying(battery=19.0, voltage=16.0, cells=4), "19.0% <= low_battery 20%"),
        (LOW_VOLTS, "3.40 V per cell"),
        (LOW_WARNING, "charge_state LOW"),
    ],
    ids=["percent", "volts", "warning"],
)
def test_low_battery_reason_says_which(snapshot: VehicleState, words: str) -> None:
    h = hlc_in(H.AIRBORNE)
    outcome = h.on_vehicle(snapshot, T0 + 20)
    assert h.state is H.LOW_BATTERY
    assert words in outcome.reason and words in outcome.errors[0].text


@pytest.mark.parametrize(
    "snapshot",
    [flying(voltage=float("nan"), cells=4), flying(voltage=13.6, cells=0), flying(voltage=14.4, cells=4)],
    ids=["nan-volts", "no-cells", "3.6V"],
)
def test_unknown_or_healthy_voltage_is_not_low(snapshot: VehicleState) -> None:
    h = hlc_in(H.AIRBORNE)
    assert h.on_vehicle(snapshot, T0 + 20).transition is None


def test_takeoff_refused_on_low_cell_voltage_says_so() -> None:
    h = hlc_in(H.READY, HlcParams(low_cell_voltage=3.7))
    h.on_vehicle(replace(GROUND, voltage=14.6, cells=4), T0 + 1)  # 3.65 V per cell
    outcome = h.on_mc_state(M.TAKEOFF, T0 + 2)
    assert h.state is H.READY and outcome.errors[0].code is ErrorCode.TAKEOFF_REFUSED_LOW_BATTERY
    assert "V per cell" in outcome.errors[0].text


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_low_cell_voltage_validated(value: float) -> None:
    with pytest.raises(ValueError, match="low_cell_voltage"):
        HlcParams(low_cell_voltage=value)


def test_closed_loop_link_regained_in_the_air_returns_home_by_policy() -> None:
    loop = Loop()
    loop.run(1.0)
    loop.command(Command.TAKEOFF, 1)
    loop.run(6.0)
    assert (loop.mc.state, loop.hlc.state) == (M.MISSION, H.AIRBORNE)
    loop.sim.set_link_loss(True)
    loop.run(4.0)
    assert (loop.mc.state, loop.hlc.state) == (M.ERROR, H.LLC_DOWN)
    loop.sim.set_link_loss(False)
    loop.run(0.3)
    assert (H.LLC_DOWN, H.HOLD) in loop.hlc_log and (M.ERROR, M.RTL) in loop.mc_log
    assert "on_link_regained = rtl" in loop.mc.reason
    assert (loop.mc.state, loop.hlc.state) == (M.RTL, H.RTL)
    assert loop.sim.state().mode == "RTL"
    loop.run(20.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    assert loop.errors == [ErrorCode.LINK_LOST, ErrorCode.LINK_REGAINED]


def test_closed_loop_fence_brake_holds_until_the_operator_lands() -> None:
    loop = Loop()
    loop.run(1.0)
    loop.command(Command.TAKEOFF, 1)
    loop.run(6.0)
    loop.sim.trigger_failsafe("brake", "fence breach")
    loop.run(2.0)
    assert (loop.mc.state, loop.hlc.state) == (M.HOLD, H.HOLD)
    assert "fence breach" in loop.hlc.reason and loop.sim.state().in_air
    loop.command(Command.LAND, 2)
    loop.run(10.0)
    assert (loop.mc.state, loop.hlc.state) == (M.STANDBY, H.READY)
    assert loop.errors == [ErrorCode.AUTOPILOT_FAILSAFE]
    assert M.MANUAL not in {to for _, to in loop.mc_log}
