"""The HLC transition table (docs/design.md §6), read top to bottom: the first row of the state
taking the event whose guard holds wins. The guards and effects its rows name are defined just above
it, over `HlcView` (what they may read of the machine); :mod:`antalate_lcm.agent.hlc.machine` derives
the events and applies the rows.

Failsafe rows (docs/design.md §6 and docs/failsafes.md), and the choices behind them
-------------------------------------------------------------------------------
* **LLC_DOWN is recoverable.** When the link is fresh again (``link_age < link_timeout``) the HLC
  re-reads the vehicle with `classify`, as INIT does: on the ground -> READY; in the air the
  autopilot's RTL/LAND/failsafe-HOLD or a pilot -> RTL/LANDING/HOLD/MANUAL; still in GUIDED -> HOLD
  with a HOVER action: the vehicle stops until the MC decides (its ``on_link_regained`` policy).
  Every such row publishes a LINK_REGAINED ``hlc_error_t`` saying what the vehicle does.
* **Autopilot failsafes are not pilots.** `VehicleState.failsafe` with flight_mode RTL, LANDING or
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
  or the vehicle's own `VehicleState.battery_warning`; the reason says which.

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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from antalate_lcm.agent.hlc.effects import Action, ErrorCode, HlcError
from antalate_lcm.agent.hlc.events import HlcEvent
from antalate_lcm.base.state_machine import Row, Table
from antalate_lcm.wire.vocabulary import HlcState, McState, Severity


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


__all__ = ["HLC_TABLE", "HlcRow", "HlcView"]
