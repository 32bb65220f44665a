"""The High-Level Control state machine (docs/design.md §6) as an explicit transition table.

Pure logic: no I/O, no clock. The HLC node feeds it three kinds of input and performs what comes out:

* `HighLevelControl.on_mc_state(state, now, takeoff_altitude=...)` -- every ``mc_state_t`` heard;
* `HighLevelControl.on_autopilot(snapshot, now)` -- every `AutopilotState` polled (10 Hz or more);
* `HighLevelControl.on_action_result(kind, ok, now)` -- the result of an `Action` the node performed;
* `HighLevelControl.tick(now)` -- periodically, for timeouts.

Each call returns an `HlcOutcome`: at most one `HlcTransition`, the `Action` s to perform on the
autopilot, in order, and the `HlcError` s to publish as ``hlc_error_t``.

How inputs become events
------------------------
* **MC TAKEOFF is edge-triggered**: it fires once, when the MC state *changes* to TAKEOFF. The MC
  republishes its state at 5 Hz; were it level-triggered, an HLC that just fell back to READY after a
  failed arm would re-arm on the next republish, before the MC had seen the failure. It also means an
  HLC that starts while the MC is already in TAKEOFF does not take off on a stale command (the MC
  times out to STANDBY and the operator asks again).
* **MC LAND / MC RTL are level-triggered**: every observation counts, so a safety command cannot be
  lost because it arrived while the HLC was busy (e.g. arming) -- it is honoured in the next state.
* Autopilot observations yield at most one event each, the first with a matching row, in this
  priority order: LINK_LOST, (in LLC_DOWN only) LINK_REGAINED_*, LANDED, PILOT_TAKEOVER, INIT resync
  / LINK_UP, FAILSAFE_*, AUTOPILOT_LAND, AUTOPILOT_RTL, LOW_BATTERY, ALTITUDE_REACHED.

Failsafe rows (docs/design.md §6 and docs/failsafes.md), and the choices behind them
-------------------------------------------------------------------------------
* **LLC_DOWN is recoverable.** When the link is fresh again (``link_age < link_timeout``) the HLC
  re-reads the vehicle with `classify`, as INIT does: on the ground -> READY; in the air the
  autopilot's RTL/LAND/failsafe-HOLD or a pilot -> RTL/LANDING/HOLD/MANUAL; still in GUIDED -> HOLD
  with a HOVER action: the vehicle stops until the MC decides (its ``on_link_regained`` policy).
  Every such row publishes a LINK_REGAINED ``hlc_error_t`` saying what the vehicle does.
* **Autopilot failsafes are not pilots.** `AutopilotState.failsafe` with flight_mode RTL, LANDING or
  HOLD is the autopilot's decision (fence, battery, EKF, GCS failsafe): the HLC follows the vehicle
  from any flying state (FAILSAFE_RTL/LAND/HOLD rows, a WARNING AUTOPILOT_FAILSAFE error carrying
  the reason), never MANUAL. Only a real pilot (`pilot_in_control`) makes MANUAL; HOLD without a
  failsafe is a pilot's BRAKE. A failsafe RTL does not move LOW_BATTERY (already returning).
* **HOLD** waits for the MC: MC RTL / MC LAND -> RTL / LANDING with the action, but only when the
  MC has been in another state since HOLD began (`mc_moved`): an MC RTL republished before the MC
  heard the autopilot's fence BRAKE must not override that BRAKE. The same guard applies to the
  new RTL/LOW_BATTERY + MC LAND rows (land now instead of flying home). AIRBORNE + MC HOLD -> HOLD
  with HOVER (an MC holding by policy after an HLC restart). HOLD counts as a flying, autonomous
  state for the low-battery, pilot-takeover, landed and link-lost rows -- the low-battery row once a
  flight (until READY): a failsafe Hold that comes after the HLC's own LOW_BATTERY RTL (PX4's battery
  failsafe holds COM_FAIL_ACT_T before its action) stays HOLD, where LOW_BATTERY and FAILSAFE_HOLD
  would otherwise alternate at the poll rate, an RTL command each time (seen with PX4 1.15.4 SITL).
* **Low battery** is the first of: percentage <= ``low_battery``, volts per cell <= ``low_cell_voltage``,
  or the vehicle's own `AutopilotState.battery_warning`; the reason says which.

Rows beyond docs/design.md §6, and why
------------------------------
* GAINING_ALTITUDE + the TAKEOFF action failed -> LANDING with LAND (an ERROR): a vehicle with no
  separate arming step (a Tello) refuses at takeoff, not at arm; waiting out gain_altitude_timeout
  for a takeoff that was refused would only delay the operator. LAND is harmless on the ground and
  disarms, so the LANDED row then brings the HLC back to READY.
* GAINING_ALTITUDE + MC LAND/RTL -> LANDING/RTL: the MC accepts LAND/RTL in its TAKEOFF state
  (docs/design.md §5), which maps to our TAKEOFF and GAINING_ALTITUDE; the HLC must follow.
* TAKEOFF + armed while the MC is no longer in TAKEOFF -> READY with DISARM (an INFO error): the
  operator cancelled while we were arming; taking off just to land again would be absurd.
* AIRBORNE + landed and disarmed -> READY (WARNING): the vehicle came down on its own (e.g. a Tello's
  own low-battery landing); the HLC must not stay "airborne" on the ground.
* GAINING_ALTITUDE/AIRBORNE + the autopilot switched to its own RTL / LAND (a failsafe) -> RTL /
  LANDING, with no action (it is already doing it) and a WARNING; and RTL + autopilot LAND mode ->
  LANDING, for adapters that report the final descent of an RTL as a landing. This keeps the
  published state truthful, and lets the MC follow (its "RTL + HLC LANDING -> LAND" row).

Interpretation of docs/design.md §6 where it leaves room
-----------------------------------------------
* LLC_DOWN applies to every state except INIT (at start-up a vehicle that is not powered yet is
  normal: INIT simply waits) and LLC_DOWN itself.
* "Autonomous states" for the pilot-takeover row are GAINING_ALTITUDE, AIRBORNE, RTL, LANDING and
  LOW_BATTERY; TAKEOFF is left out because the vehicle is on the ground and the adapter's ``arm()``
  is what switches it into its autonomous mode. A takeover needs the vehicle armed and not under
  computer control, so a stale snapshot from before the arm cannot fake one.
* "Flying states" for the low-battery row are GAINING_ALTITUDE and AIRBORNE: in RTL and LANDING the
  vehicle is already coming down (re-commanding RTL there would waste the remaining charge), and in
  MANUAL a pilot has control. The row fires once because LOW_BATTERY has no low-battery row.
* An unknown battery level (-1) is never "low".
* The takeoff target is the altitude requested with the MC's TAKEOFF (``takeoff_altitude``; 0 means
  `HlcParams.default_takeoff_altitude`), latched when the HLC leaves READY.

Error codes are the `ErrorCode` enum below (``hlc_error_t.code``).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import ClassVar, Protocol

from antalate_lcm.autopilot.base import AutopilotState, FlightMode, altitude_reached
from antalate_lcm.base.state_machine import Row, Table, Transition
from antalate_lcm.wire.vocabulary import HlcState, McState, Severity


class ErrorCode(enum.IntEnum):
    """``hlc_error_t.code`` values raised by the HLC; stable, so operators' tools can match on them."""

    TAKEOFF_REFUSED_LOW_BATTERY = 1
    ARM_FAILED = 2
    GAIN_ALTITUDE_TIMEOUT = 3
    LOW_BATTERY = 4
    PILOT_TAKEOVER = 5
    LINK_LOST = 6
    ACTION_FAILED = 7
    UNEXPECTED_LANDING = 8
    TAKEOFF_CANCELLED = 9
    AUTOPILOT_TOOK_OVER = 10
    TAKEOFF_REFUSED = 11
    AUTOPILOT_FAILSAFE = 12  # the autopilot's own failsafe changed the mode; the text carries its reason
    LINK_REGAINED = 13  # the autopilot answers again after LLC_DOWN; the text says what the vehicle does
    #: The safety filter changed a velocity (separation or fence), or cannot keep its promise; the
    #: text names who changed it, the nearest peer and its distance (docs/safety.md).
    SAFETY = 14


@dataclass(frozen=True)
class HlcError:
    """An ``hlc_error_t`` to publish."""

    code: ErrorCode
    severity: Severity
    text: str


class ActionKind(enum.Enum):
    """Autopilot calls the node performs for the machine (`Autopilot` method of the same name)."""

    ARM = "ARM"
    DISARM = "DISARM"
    TAKEOFF = "TAKEOFF"
    LAND = "LAND"
    RTL = "RTL"
    HOVER = "HOVER"  # set_velocity(0, 0, 0, 0, Frame.BODY)


@dataclass(frozen=True)
class Action:
    """One autopilot call; `altitude` is only meaningful for TAKEOFF (metres above home)."""

    kind: ActionKind
    altitude: float = 0.0

    ARM: ClassVar[Action]
    DISARM: ClassVar[Action]
    LAND: ClassVar[Action]
    RTL: ClassVar[Action]
    HOVER: ClassVar[Action]

    @classmethod
    def takeoff(cls, altitude: float) -> Action:
        return cls(ActionKind.TAKEOFF, altitude)

    def __str__(self) -> str:
        if self.kind is ActionKind.TAKEOFF:
            return f"TAKEOFF({self.altitude:g} m)"
        return self.kind.name


Action.ARM = Action(ActionKind.ARM)
Action.DISARM = Action(ActionKind.DISARM)
Action.LAND = Action(ActionKind.LAND)
Action.RTL = Action(ActionKind.RTL)
Action.HOVER = Action(ActionKind.HOVER)


class HlcEvent(enum.Enum):
    """Inputs of the table, derived from observations (see the module docstring)."""

    # Members are singletons compared by identity: identity's hash (in C) instead of Enum's, which
    # hashes the name in Python on every table lookup (several per control tick per agent).
    __hash__ = object.__hash__

    LINK_UP = "LINK_UP"  # INIT: autopilot connected, link fresh, MC heard, vehicle on the ground
    RESYNC_AIRBORNE = "RESYNC_AIRBORNE"  # INIT: armed and in air, autopilot in GUIDED
    RESYNC_LANDING = "RESYNC_LANDING"  # INIT: armed and in air, autopilot landing
    RESYNC_RTL = "RESYNC_RTL"  # INIT: armed and in air, autopilot returning
    RESYNC_MANUAL = "RESYNC_MANUAL"  # INIT: armed and in air, a pilot in control
    MC_TAKEOFF = "MC_TAKEOFF"  # MC changed to TAKEOFF (edge)
    MC_LAND = "MC_LAND"  # MC is in LAND (level)
    MC_RTL = "MC_RTL"  # MC is in RTL (level)
    ARMED = "ARMED"  # result of Action.ARM
    ARM_FAILED = "ARM_FAILED"  # result of Action.ARM
    TAKEOFF_FAILED = "TAKEOFF_FAILED"  # result of Action.TAKEOFF
    ALTITUDE_REACHED = "ALTITUDE_REACHED"
    GAIN_ALTITUDE_TIMEOUT = "GAIN_ALTITUDE_TIMEOUT"
    LANDED = "LANDED"  # on the ground and disarmed
    PILOT_TAKEOVER = "PILOT_TAKEOVER"  # armed and no longer under computer control
    LOW_BATTERY = "LOW_BATTERY"
    LINK_LOST = "LINK_LOST"  # link_age >= link_timeout
    AUTOPILOT_LAND = "AUTOPILOT_LAND"  # the autopilot reports it is landing on its own
    AUTOPILOT_RTL = "AUTOPILOT_RTL"  # the autopilot reports it is returning on its own
    RESYNC_HOLD = "RESYNC_HOLD"  # INIT: armed and in air, autopilot holding on a failsafe
    MC_HOLD = "MC_HOLD"  # MC is in HOLD (level)
    FAILSAFE_RTL = "FAILSAFE_RTL"  # AutopilotState.failsafe set, flight_mode RTL
    FAILSAFE_LAND = "FAILSAFE_LAND"  # AutopilotState.failsafe set, flight_mode LANDING
    FAILSAFE_HOLD = "FAILSAFE_HOLD"  # AutopilotState.failsafe set, flight_mode HOLD
    LINK_REGAINED_GROUND = "LINK_REGAINED_GROUND"  # LLC_DOWN: fresh again, vehicle on the ground
    LINK_REGAINED_GUIDED = "LINK_REGAINED_GUIDED"  # LLC_DOWN: fresh again, flying in GUIDED
    LINK_REGAINED_RTL = "LINK_REGAINED_RTL"  # LLC_DOWN: fresh again, autopilot returning
    LINK_REGAINED_LANDING = "LINK_REGAINED_LANDING"  # LLC_DOWN: fresh again, autopilot landing
    LINK_REGAINED_HOLD = "LINK_REGAINED_HOLD"  # LLC_DOWN: fresh again, autopilot holding on a failsafe
    LINK_REGAINED_MANUAL = "LINK_REGAINED_MANUAL"  # LLC_DOWN: fresh again, a pilot in control


class Control(enum.Enum):
    """Who flies the vehicle and how, read from one snapshot (`classify`)."""

    GROUND = "GROUND"  # not (armed and in the air)
    GUIDED = "GUIDED"  # flying under our commands
    RTL = "RTL"  # the autopilot returns on its own (failsafe or not)
    LANDING = "LANDING"  # the autopilot lands on its own
    HOLD = "HOLD"  # the autopilot holds position on a failsafe (fence BRAKE)
    PILOT = "PILOT"  # a human pilot


_FAILSAFE_MODES = (FlightMode.RTL, FlightMode.LANDING, FlightMode.HOLD)


def pilot_in_control(ap: AutopilotState) -> bool:
    """A human pilot has the vehicle: not autonomous, or a pilot's mode, unless a failsafe explains it.

    An autopilot failsafe (`AutopilotState.failsafe` with RTL, LANDING or HOLD) is the autopilot's
    own decision, never a pilot's, even when the adapter says the vehicle left our control. HOLD
    without a failsafe is a pilot's BRAKE.
    """
    if ap.failsafe and ap.flight_mode in _FAILSAFE_MODES:
        return False
    return not ap.autonomous or ap.flight_mode in (FlightMode.MANUAL, FlightMode.HOLD)


def classify(ap: AutopilotState) -> Control:
    """What the vehicle is doing, for the resync rows (INIT, and LLC_DOWN when the link is back)."""
    if not (ap.armed and ap.in_air):
        return Control.GROUND
    if pilot_in_control(ap):
        return Control.PILOT
    return {
        FlightMode.RTL: Control.RTL,
        FlightMode.LANDING: Control.LANDING,
        FlightMode.HOLD: Control.HOLD,
    }.get(ap.flight_mode, Control.GUIDED)  # type: ignore[arg-type]


@dataclass(frozen=True)
class HlcParams:
    """HLC tunables (the ``[hlc]`` config table)."""

    default_takeoff_altitude: float = 10.0  # m above home, when the MC's TAKEOFF carries 0
    airborne_fraction: float = 0.95  # of the target altitude, to count as AIRBORNE
    gain_altitude_timeout: float = 30.0  # s in GAINING_ALTITUDE before giving up and landing
    low_battery: float = 20.0  # percent; at or below: refuse takeoff / return home
    link_timeout: float = 3.0  # s without autopilot heartbeat -> LLC_DOWN
    low_cell_voltage: float = 3.5  # V per cell; at or below: low battery (when the adapter knows it)

    def __post_init__(self) -> None:
        for name in ("default_takeoff_altitude", "gain_altitude_timeout", "link_timeout", "low_cell_voltage"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"HlcParams.{name} must be a positive number, got {value!r}")
        if not (0.0 < self.airborne_fraction <= 1.0):
            raise ValueError(f"HlcParams.airborne_fraction must be in (0, 1], got {self.airborne_fraction!r}")
        if not (0.0 <= self.low_battery < 100.0):
            raise ValueError(f"HlcParams.low_battery must be in [0, 100), got {self.low_battery!r}")


#: A state change, with the event and a human-readable reason, for the node's log.
HlcTransition = Transition[HlcState, HlcEvent]


@dataclass(frozen=True)
class HlcOutcome:
    """What one input did: the transition (if any), actions to perform in order, errors to publish."""

    transition: HlcTransition | None = None
    actions: tuple[Action, ...] = ()
    errors: tuple[HlcError, ...] = ()
    reason: str = ""

    @property
    def changed(self) -> bool:
        return self.transition is not None


#: The outcome of an input that changed nothing (immutable, so one serves every tick).
NOTHING = HlcOutcome()

# Enum members read on every snapshot (20 a second per agent) and MC state (5), bound once: in
# CPython 3.11 ``HlcEvent.LANDED`` calls the enum's descriptor (~125 ns; a global read is ~10).
_E_LANDED, _E_PILOT_TAKEOVER, _E_AUTOPILOT_LAND = (
    HlcEvent.LANDED,
    HlcEvent.PILOT_TAKEOVER,
    HlcEvent.AUTOPILOT_LAND,
)
_E_AUTOPILOT_RTL, _E_LOW_BATTERY = HlcEvent.AUTOPILOT_RTL, HlcEvent.LOW_BATTERY
_E_ALTITUDE_REACHED = HlcEvent.ALTITUDE_REACHED
_S_INIT, _S_LLC_DOWN, _S_GAINING_ALTITUDE = HlcState.INIT, HlcState.LLC_DOWN, HlcState.GAINING_ALTITUDE
_F_LANDING, _F_RTL = FlightMode.LANDING, FlightMode.RTL
_MC_TAKEOFF, _MC_LAND, _MC_RTL, _MC_HOLD = McState.TAKEOFF, McState.LAND, McState.RTL, McState.HOLD


class HlcView(Protocol):
    """What the HLC table's guards and effects may read of the machine (read-only: see
    `antalate_lcm.base.state_machine`)."""

    @property
    def mc_state(self) -> int | None: ...
    @property
    def mc_moved(self) -> bool: ...
    @property
    def low_battery_handled(self) -> bool: ...
    @property
    def target_altitude(self) -> float: ...
    def battery_low_reason(self) -> str: ...


_Effect = Callable[[HlcView, str], tuple[tuple[Action, ...], tuple[HlcError, ...]]]


@dataclass(frozen=True)
class HlcRow(Row[HlcState, HlcEvent, HlcView]):
    """A row of the HLC table: `Row` (`target` None means "stay": a refusal that only reports an error;
    `extra`: not in docs/design.md §6, see the module docstring) and the `effect` that yields the actions
    to perform and the errors to publish."""

    effect: _Effect | None = None


def _fx(*actions: Action, error: tuple[ErrorCode, Severity] | None = None) -> _Effect:
    """An effect that performs `actions` and, optionally, reports an error whose text is the detail."""

    def effect(_m: HlcView, detail: str) -> tuple[tuple[Action, ...], tuple[HlcError, ...]]:
        errors = () if error is None else (HlcError(error[0], error[1], detail),)
        return actions, errors

    return effect


def _fx_climb(m: HlcView, _detail: str) -> tuple[tuple[Action, ...], tuple[HlcError, ...]]:
    return (Action.takeoff(m.target_altitude),), ()


def _battery_low(m: HlcView) -> bool:
    return bool(m.battery_low_reason())


def _mc_left_takeoff(m: HlcView) -> bool:
    return m.mc_state != McState.TAKEOFF


def _mc_changed_since_entry(m: HlcView) -> bool:
    """The MC has been in another state since this HLC state began (see the module docstring)."""
    return m.mc_moved


def _battery_not_handled(m: HlcView) -> bool:
    """No LOW_BATTERY yet this flight (see the module docstring: HOLD's low-battery row fires once)."""
    return not m.low_battery_handled


def _s(*states: HlcState) -> frozenset[HlcState]:
    return frozenset(states)


S = HlcState
E = HlcEvent
_AUTONOMOUS = _s(S.GAINING_ALTITUDE, S.AIRBORNE, S.RTL, S.LANDING, S.LOW_BATTERY, S.HOLD)
_FLYING = _AUTONOMOUS | {S.MANUAL}
_FAILSAFE = (ErrorCode.AUTOPILOT_FAILSAFE, Severity.WARNING)
_REGAINED = (ErrorCode.LINK_REGAINED, Severity.WARNING)
_ALL_BUT_INIT = frozenset(S) - {S.INIT, S.LLC_DOWN}

#: The HLC transition table, in priority order (the first row matching state, event and guard wins).
HLC_TABLE: Table[HlcState, HlcEvent, HlcView, HlcRow] = Table(
    (
        HlcRow(
            _ALL_BUT_INIT,
            E.LINK_LOST,
            S.LLC_DOWN,
            "autopilot link lost",
            effect=_fx(error=(ErrorCode.LINK_LOST, Severity.CRITICAL)),
        ),
        HlcRow(_s(S.INIT), E.LINK_UP, S.READY, "autopilot connected and MC heard"),
        HlcRow(_s(S.INIT), E.RESYNC_AIRBORNE, S.AIRBORNE, "restart resync: vehicle flying under our control"),
        HlcRow(_s(S.INIT), E.RESYNC_LANDING, S.LANDING, "restart resync: vehicle landing"),
        HlcRow(_s(S.INIT), E.RESYNC_RTL, S.RTL, "restart resync: vehicle returning to launch"),
        HlcRow(_s(S.INIT), E.RESYNC_MANUAL, S.MANUAL, "restart resync: pilot in control"),
        HlcRow(_s(S.INIT), E.RESYNC_HOLD, S.HOLD, "restart resync: autopilot holding on a failsafe"),
        HlcRow(
            _s(S.LLC_DOWN),
            E.LINK_REGAINED_GROUND,
            S.READY,
            "autopilot link regained, vehicle on the ground",
            effect=_fx(error=(ErrorCode.LINK_REGAINED, Severity.INFO)),
        ),
        HlcRow(
            _s(S.LLC_DOWN),
            E.LINK_REGAINED_GUIDED,
            S.HOLD,
            "autopilot link regained in the air: stop and wait for the MC",
            effect=_fx(Action.HOVER, error=_REGAINED),
        ),
        HlcRow(
            _s(S.LLC_DOWN),
            E.LINK_REGAINED_RTL,
            S.RTL,
            "autopilot link regained, vehicle returning",
            effect=_fx(error=_REGAINED),
        ),
        HlcRow(
            _s(S.LLC_DOWN),
            E.LINK_REGAINED_LANDING,
            S.LANDING,
            "autopilot link regained, vehicle landing",
            effect=_fx(error=_REGAINED),
        ),
        HlcRow(
            _s(S.LLC_DOWN),
            E.LINK_REGAINED_HOLD,
            S.HOLD,
            "autopilot link regained, vehicle holding",
            effect=_fx(error=_REGAINED),
        ),
        HlcRow(
            _s(S.LLC_DOWN),
            E.LINK_REGAINED_MANUAL,
            S.MANUAL,
            "autopilot link regained, pilot in control",
            effect=_fx(error=_REGAINED),
        ),
        HlcRow(
            _s(S.READY),
            E.MC_TAKEOFF,
            None,
            "takeoff refused: battery low",
            guard=_battery_low,
            effect=_fx(error=(ErrorCode.TAKEOFF_REFUSED_LOW_BATTERY, Severity.ERROR)),
        ),
        # Entering TAKEOFF latches the requested altitude (`HighLevelControl._fire`) before the effects run.
        HlcRow(_s(S.READY), E.MC_TAKEOFF, S.TAKEOFF, "MC TAKEOFF: arming", effect=_fx(Action.ARM)),
        HlcRow(
            _s(S.TAKEOFF),
            E.ARMED,
            S.READY,
            "takeoff cancelled by the MC while arming",
            guard=_mc_left_takeoff,
            effect=_fx(Action.DISARM, error=(ErrorCode.TAKEOFF_CANCELLED, Severity.INFO)),
            extra=True,
        ),
        HlcRow(_s(S.TAKEOFF), E.ARMED, S.GAINING_ALTITUDE, "armed: taking off", effect=_fx_climb),
        HlcRow(
            _s(S.TAKEOFF),
            E.ARM_FAILED,
            S.READY,
            "arming failed",
            effect=_fx(error=(ErrorCode.ARM_FAILED, Severity.ERROR)),
        ),
        HlcRow(
            _s(S.GAINING_ALTITUDE),
            E.ALTITUDE_REACHED,
            S.AIRBORNE,
            "altitude reached",
            effect=_fx(Action.HOVER),
        ),
        HlcRow(
            _s(S.GAINING_ALTITUDE),
            E.TAKEOFF_FAILED,
            S.LANDING,
            "the autopilot refused the takeoff: landing",
            effect=_fx(Action.LAND, error=(ErrorCode.TAKEOFF_REFUSED, Severity.ERROR)),
            extra=True,
        ),
        HlcRow(
            _s(S.GAINING_ALTITUDE),
            E.GAIN_ALTITUDE_TIMEOUT,
            S.LANDING,
            "altitude not gained in time: landing",
            effect=_fx(Action.LAND, error=(ErrorCode.GAIN_ALTITUDE_TIMEOUT, Severity.WARNING)),
        ),
        HlcRow(_s(S.AIRBORNE), E.MC_RTL, S.RTL, "MC RTL", effect=_fx(Action.RTL)),
        HlcRow(_s(S.AIRBORNE), E.MC_LAND, S.LANDING, "MC LAND", effect=_fx(Action.LAND)),
        HlcRow(
            _s(S.GAINING_ALTITUDE),
            E.MC_RTL,
            S.RTL,
            "MC RTL during takeoff",
            effect=_fx(Action.RTL),
            extra=True,
        ),
        HlcRow(
            _s(S.GAINING_ALTITUDE),
            E.MC_LAND,
            S.LANDING,
            "MC LAND during takeoff",
            effect=_fx(Action.LAND),
            extra=True,
        ),
        HlcRow(
            _s(S.RTL, S.LANDING, S.LOW_BATTERY, S.MANUAL, S.HOLD), E.LANDED, S.READY, "landed and disarmed"
        ),
        HlcRow(
            _s(S.AIRBORNE),
            E.LANDED,
            S.READY,
            "vehicle landed on its own",
            effect=_fx(error=(ErrorCode.UNEXPECTED_LANDING, Severity.WARNING)),
            extra=True,
        ),
        HlcRow(
            _AUTONOMOUS,
            E.PILOT_TAKEOVER,
            S.MANUAL,
            "pilot took over",
            effect=_fx(error=(ErrorCode.PILOT_TAKEOVER, Severity.WARNING)),
        ),
        # The autopilot's failsafes: follow the vehicle, never MANUAL (the failsafe's reason is in the error).
        HlcRow(
            _FLYING - {S.RTL, S.LOW_BATTERY},
            E.FAILSAFE_RTL,
            S.RTL,
            "autopilot failsafe: returning",
            effect=_fx(error=_FAILSAFE),
        ),
        HlcRow(
            _FLYING - {S.LANDING},
            E.FAILSAFE_LAND,
            S.LANDING,
            "autopilot failsafe: landing",
            effect=_fx(error=_FAILSAFE),
        ),
        HlcRow(
            _FLYING - {S.HOLD},
            E.FAILSAFE_HOLD,
            S.HOLD,
            "autopilot failsafe: holding position",
            effect=_fx(error=_FAILSAFE),
        ),
        # HOLD waits for the MC; the MC's RTL/LAND must be new since HOLD began (not a republish).
        HlcRow(_s(S.HOLD), E.MC_RTL, S.RTL, "MC RTL", guard=_mc_changed_since_entry, effect=_fx(Action.RTL)),
        HlcRow(
            _s(S.HOLD),
            E.MC_LAND,
            S.LANDING,
            "MC LAND",
            guard=_mc_changed_since_entry,
            effect=_fx(Action.LAND),
        ),
        HlcRow(
            _s(S.RTL, S.LOW_BATTERY),
            E.MC_LAND,
            S.LANDING,
            "MC LAND while returning",
            guard=_mc_changed_since_entry,
            effect=_fx(Action.LAND),
        ),
        HlcRow(_s(S.AIRBORNE), E.MC_HOLD, S.HOLD, "MC HOLD: stop and wait", effect=_fx(Action.HOVER)),
        HlcRow(
            _s(S.HOLD),
            E.AUTOPILOT_LAND,
            S.LANDING,
            "autopilot landing on its own",
            effect=_fx(error=(ErrorCode.AUTOPILOT_TOOK_OVER, Severity.WARNING)),
        ),
        HlcRow(
            _s(S.HOLD),
            E.AUTOPILOT_RTL,
            S.RTL,
            "autopilot returning on its own",
            effect=_fx(error=(ErrorCode.AUTOPILOT_TOOK_OVER, Severity.WARNING)),
        ),
        HlcRow(
            _s(S.GAINING_ALTITUDE, S.AIRBORNE),
            E.AUTOPILOT_LAND,
            S.LANDING,
            "autopilot landing on its own",
            effect=_fx(error=(ErrorCode.AUTOPILOT_TOOK_OVER, Severity.WARNING)),
            extra=True,
        ),
        HlcRow(_s(S.RTL), E.AUTOPILOT_LAND, S.LANDING, "RTL final descent", extra=True),
        HlcRow(
            _s(S.GAINING_ALTITUDE, S.AIRBORNE),
            E.AUTOPILOT_RTL,
            S.RTL,
            "autopilot returning on its own",
            effect=_fx(error=(ErrorCode.AUTOPILOT_TOOK_OVER, Severity.WARNING)),
            extra=True,
        ),
        HlcRow(
            _s(S.GAINING_ALTITUDE, S.AIRBORNE),
            E.LOW_BATTERY,
            S.LOW_BATTERY,
            "battery low: returning home",
            effect=_fx(Action.RTL, error=(ErrorCode.LOW_BATTERY, Severity.WARNING)),
        ),
        HlcRow(
            _s(S.HOLD),
            E.LOW_BATTERY,
            S.LOW_BATTERY,
            "battery low: returning home",
            guard=_battery_not_handled,
            effect=_fx(Action.RTL, error=(ErrorCode.LOW_BATTERY, Severity.WARNING)),
        ),
    )
)
del S, E


class HighLevelControl:
    """The HLC machine. Read `state`; feed observations; perform the returned actions."""

    def __init__(
        self,
        params: HlcParams | None = None,
        *,
        table: Table[HlcState, HlcEvent, HlcView, HlcRow] = HLC_TABLE,
    ) -> None:
        self.params = params or HlcParams()
        self._table = table
        self.state: HlcState = HlcState.INIT
        self.entered_at: float | None = None  # `now` of the last transition
        self.mc_state: int | None = None  # last MC state heard (an McState value), None = never
        self.autopilot: AutopilotState | None = None  # last snapshot
        self.mc_state_at_entry: int | None = None  # the MC's state when `state` began
        self.low_battery_handled = False  # LOW_BATTERY was entered since the last READY
        self.mc_moved = False  # the MC has been in another state than `mc_state_at_entry` since
        self.reason = "waiting for the autopilot and the MC"  # why the HLC is in `state` (hlc_state_t.reason)
        self._mc_takeoff_altitude = 0.0
        self._target_altitude = 0.0

    # ----------------------------------------------------------------- queries

    @property
    def target_altitude(self) -> float:
        """The altitude of the current/last takeoff (m above home), 0 before the first one."""
        return self._target_altitude

    @property
    def mc_heard(self) -> bool:
        return self.mc_state is not None

    def _requested_altitude(self) -> float:
        requested = self._mc_takeoff_altitude
        if math.isfinite(requested) and requested > 0.0:
            return requested
        return self.params.default_takeoff_altitude

    def battery_low_reason(self) -> str:
        """Why the battery counts as low ("" if it does not): percentage, volts per cell or the vehicle's
        own warning, whichever comes first. Unknown values (-1 %, NaN V) are never low."""
        ap, p = self.autopilot, self.params
        if ap is None:
            return ""
        if ap.battery_known and ap.battery <= p.low_battery:
            return f"battery {ap.battery:.1f}% <= low_battery {p.low_battery:g}%"
        cell = ap.cell_voltage
        if math.isfinite(cell) and cell <= p.low_cell_voltage:
            return (
                f"battery {cell:.2f} V per cell ({ap.voltage:.1f} V / {ap.cells} cells)"
                f" <= low_cell_voltage {p.low_cell_voltage:g} V"
            )
        if ap.battery_warning:
            return f"the autopilot reports the battery low: {ap.battery_warning}"
        return ""

    # ----------------------------------------------------------------- inputs

    def on_mc_state(self, state: McState | int, now: float, *, takeoff_altitude: float = 0.0) -> HlcOutcome:
        """An ``mc_state_t`` was heard. `takeoff_altitude` is the MC's requested altitude (0 = default)."""
        previous, self.mc_state = self.mc_state, int(state)
        if self.mc_state != self.mc_state_at_entry:
            self.mc_moved = True
        events: list[tuple[HlcEvent, str]] = []
        if state == _MC_TAKEOFF:
            self._mc_takeoff_altitude = takeoff_altitude
            if previous != _MC_TAKEOFF:
                events.append((HlcEvent.MC_TAKEOFF, self._takeoff_detail()))
        elif state == _MC_LAND:
            events.append((HlcEvent.MC_LAND, "MC is in LAND"))
        elif state == _MC_RTL:
            events.append((HlcEvent.MC_RTL, "MC is in RTL"))
        elif state == _MC_HOLD:
            events.append((HlcEvent.MC_HOLD, "MC is in HOLD"))
        if self.state is _S_INIT:
            events.extend(self._init_events())
        # 5 a second (the MC's republished state): nearly all with no event.
        return self._fire(events, now) if events else NOTHING

    def on_autopilot(self, snapshot: AutopilotState, now: float, *, fault: str = "") -> HlcOutcome:
        """An autopilot snapshot (the node polls `Autopilot.state()`).

        `fault` says why the snapshot is not fresh when the node knows (``state()`` raised: the node
        passes the last good snapshot with its `link_age` grown); it goes into the LLC_DOWN reason.
        """
        self.autopilot = snapshot
        events = self._autopilot_events(snapshot, fault)
        return self._fire(events, now) if events else NOTHING  # 20 a second, nearly all with none

    def on_action_result(self, kind: ActionKind, ok: bool, now: float, detail: str = "") -> HlcOutcome:
        """The outcome of an `Action` the node performed (``arm()`` False or `AutopilotError` = not ok).

        ARM results and a failed TAKEOFF drive the table; any other failed action is reported as an error, and the
        table's timeouts and observations take it from there.
        """
        suffix = f": {detail}" if detail else ""
        if kind is ActionKind.ARM:
            event = HlcEvent.ARMED if ok else HlcEvent.ARM_FAILED
            return self._fire([(event, f"arm {'succeeded' if ok else 'failed'}{suffix}")], now)
        if kind is ActionKind.TAKEOFF and not ok and self.state is HlcState.GAINING_ALTITUDE:
            return self._fire([(HlcEvent.TAKEOFF_FAILED, f"autopilot TAKEOFF failed{suffix}")], now)
        if ok:
            return NOTHING
        text = f"autopilot {kind.value} failed{suffix}"
        return HlcOutcome(errors=(HlcError(ErrorCode.ACTION_FAILED, Severity.ERROR, text),), reason=text)

    def tick(self, now: float) -> HlcOutcome:
        """Time passes: fires GAIN_ALTITUDE_TIMEOUT."""
        timeout = self.params.gain_altitude_timeout
        if (
            self.state is _S_GAINING_ALTITUDE
            and self.entered_at is not None
            and now - self.entered_at >= timeout
        ):
            detail = f"still below {self.params.airborne_fraction:g} x {self._target_altitude:g} m after {timeout:g} s"
            return self._fire([(HlcEvent.GAIN_ALTITUDE_TIMEOUT, detail)], now)
        return NOTHING

    # ----------------------------------------------------------------- event derivation

    def _takeoff_detail(self) -> str:
        ap = self.autopilot
        battery = f"{ap.battery:.1f}%" if ap is not None and ap.battery_known else "unknown"
        low = self.battery_low_reason()
        return f"MC TAKEOFF to {self._requested_altitude():g} m, " + (
            low or f"battery {battery} (low_battery {self.params.low_battery:g}%)"
        )

    def _link_fresh(self, ap: AutopilotState) -> bool:
        return ap.connected and ap.link_age < self.params.link_timeout

    def _init_events(self) -> list[tuple[HlcEvent, str]]:
        ap = self.autopilot
        if self.state is not HlcState.INIT or ap is None or not self.mc_heard or not self._link_fresh(ap):
            return []
        control = classify(ap)
        if control is Control.GROUND:
            return [(HlcEvent.LINK_UP, f"autopilot link {ap.link_age:.2f} s old, vehicle on the ground")]
        resync = {
            Control.GUIDED: HlcEvent.RESYNC_AIRBORNE,
            Control.LANDING: HlcEvent.RESYNC_LANDING,
            Control.RTL: HlcEvent.RESYNC_RTL,
            Control.HOLD: HlcEvent.RESYNC_HOLD,
            Control.PILOT: HlcEvent.RESYNC_MANUAL,
        }
        return [(resync[control], self._vehicle_detail(ap))]

    def _regained_events(self, ap: AutopilotState) -> list[tuple[HlcEvent, str]]:
        regained = {
            Control.GROUND: HlcEvent.LINK_REGAINED_GROUND,
            Control.GUIDED: HlcEvent.LINK_REGAINED_GUIDED,
            Control.LANDING: HlcEvent.LINK_REGAINED_LANDING,
            Control.RTL: HlcEvent.LINK_REGAINED_RTL,
            Control.HOLD: HlcEvent.LINK_REGAINED_HOLD,
            Control.PILOT: HlcEvent.LINK_REGAINED_MANUAL,
        }
        control = classify(ap)
        where = "on the ground" if control is Control.GROUND else self._vehicle_detail(ap)
        return [(regained[control], f"link {ap.link_age:.2f} s old after LLC_DOWN, {where}")]

    @staticmethod
    def _vehicle_detail(ap: AutopilotState) -> str:
        failsafe = f", failsafe: {ap.failsafe}" if ap.failsafe else ""
        return f"vehicle armed and in air, mode {ap.mode or '?'} at {ap.alt:.1f} m{failsafe}"

    def _autopilot_events(self, ap: AutopilotState, fault: str = "") -> list[tuple[HlcEvent, str]]:
        p = self.params
        if ap.link_age >= p.link_timeout:
            # Nothing else the snapshot says can be trusted.
            why = f"; {fault}" if fault else ""
            return [
                (
                    HlcEvent.LINK_LOST,
                    f"no autopilot heartbeat for {ap.link_age:.1f} s"
                    f" (link_timeout {p.link_timeout:g} s){why}",
                )
            ]
        if self.state is _S_LLC_DOWN:
            return self._regained_events(ap) if self._link_fresh(ap) else []
        # Only events a row of this state takes are derived (`Table.events_taken`): the rest would be
        # passed over by `_fire` anyway, and their reasons cost more than the rest of the tick.
        takes = self._table.events_taken(self.state)
        events: list[tuple[HlcEvent, str]] = []
        if _E_LANDED in takes and ap.landed:
            events.append((HlcEvent.LANDED, f"on the ground and disarmed (mode {ap.mode or '?'})"))
        if _E_PILOT_TAKEOVER in takes and ap.armed and pilot_in_control(ap):
            events.append(
                (HlcEvent.PILOT_TAKEOVER, f"autopilot left autonomous control (mode {ap.mode or '?'})")
            )
        if self.state is _S_INIT:
            events.extend(self._init_events())
        if ap.failsafe and ap.flight_mode in _FAILSAFE_MODES:
            failsafe = {
                FlightMode.RTL: HlcEvent.FAILSAFE_RTL,
                FlightMode.LANDING: HlcEvent.FAILSAFE_LAND,
                FlightMode.HOLD: HlcEvent.FAILSAFE_HOLD,
            }
            events.append(
                (
                    failsafe[ap.flight_mode],
                    f"{ap.failsafe}; autopilot switched to {ap.mode or ap.flight_mode.name}",
                )
            )
        if ap.flight_mode is _F_LANDING and _E_AUTOPILOT_LAND in takes:
            events.append((HlcEvent.AUTOPILOT_LAND, f"autopilot switched to {ap.mode or 'LAND'}"))
        if ap.flight_mode is _F_RTL and _E_AUTOPILOT_RTL in takes:
            events.append((HlcEvent.AUTOPILOT_RTL, f"autopilot switched to {ap.mode or 'RTL'}"))
        if _E_LOW_BATTERY in takes:
            low = self.battery_low_reason()
            if low:
                events.append((HlcEvent.LOW_BATTERY, low))
        if _E_ALTITUDE_REACHED in takes and altitude_reached(
            ap.alt, self._target_altitude, p.airborne_fraction
        ):
            events.append(
                (
                    HlcEvent.ALTITUDE_REACHED,
                    f"altitude {ap.alt:.2f} m >= {p.airborne_fraction:g} x {self._target_altitude:g} m",
                )
            )
        return events

    # ----------------------------------------------------------------- the table

    def _fire(self, events: Iterable[tuple[HlcEvent, str]], now: float) -> HlcOutcome:
        for event, detail in events:
            row = self._table.match(self.state, event, self)
            if row is None:
                continue
            reason = f"{row.why} ({detail})" if detail else row.why
            if row.target is HlcState.TAKEOFF:
                self._target_altitude = self._requested_altitude()  # latched when the HLC leaves READY
            actions, errors = row.effect(self, reason) if row.effect is not None else ((), ())
            if row.target is None:
                return HlcOutcome(actions=actions, errors=errors, reason=reason)
            transition = HlcTransition(self.state, row.target, event, reason, now)
            self.state = row.target
            if row.target in (HlcState.LOW_BATTERY, HlcState.READY):
                self.low_battery_handled = row.target is HlcState.LOW_BATTERY
            self.entered_at = now
            self.mc_state_at_entry = self.mc_state
            self.mc_moved = False
            self.reason = reason
            return HlcOutcome(transition, actions, errors, reason)
        return NOTHING
