"""The High-Level Control state machine (docs/design.md §6) as an explicit transition table.

Pure logic: no I/O, no clock. The HLC node feeds it three kinds of input and performs what comes out:

* `HighLevelControl.on_mc_state(state, now, takeoff_altitude=...)` -- every ``mc_state_t`` heard;
* `HighLevelControl.on_vehicle(snapshot, now)` -- every `VehicleState` polled (10 Hz or more);
* `HighLevelControl.on_action_result(kind, ok, now)` -- the result of an `Action` the node performed;
* `HighLevelControl.tick(now)` -- periodically, for timeouts.

Each call returns an `HlcOutcome`: at most one `HlcTransition`, the `Action` s to perform on the
vehicle adapter, in order, and the `HlcError` s to publish as ``hlc_error_t``.

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

The table and the reasons for its rows are :mod:`antalate_lcm.agent.hlc.table`; the events
:mod:`.events`; the actions, errors and outcomes :mod:`.effects`. Error codes are the `ErrorCode`
enum there (``hlc_error_t.code``). Every name stays importable from here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from antalate_lcm.agent.hlc.effects import (
    NOTHING,
    Action,
    ActionKind,
    ErrorCode,
    HlcError,
    HlcOutcome,
    HlcTransition,
)
from antalate_lcm.agent.hlc.events import FAILSAFE_MODES, Control, HlcEvent, classify, pilot_in_control
from antalate_lcm.agent.hlc.table import HLC_TABLE, HlcRow, HlcView
from antalate_lcm.base.deprecation import renamed_attribute
from antalate_lcm.base.state_machine import Table
from antalate_lcm.vehicles.base import FlightMode, VehicleState, altitude_reached
from antalate_lcm.wire.vocabulary import HlcState, McState, Severity


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
_F_LANDING, _F_RTL, _F_GUIDED = FlightMode.LANDING, FlightMode.RTL, FlightMode.GUIDED
_MC_TAKEOFF, _MC_LAND, _MC_RTL, _MC_HOLD = McState.TAKEOFF, McState.LAND, McState.RTL, McState.HOLD


#: The events `HighLevelControl._vehicle_events` derives from a snapshot whose link is fresh.
_FROM_SNAPSHOT = frozenset(
    {
        HlcEvent.LANDED,
        HlcEvent.PILOT_TAKEOVER,
        HlcEvent.FAILSAFE_RTL,
        HlcEvent.FAILSAFE_LAND,
        HlcEvent.FAILSAFE_HOLD,
        HlcEvent.AUTOPILOT_LAND,
        HlcEvent.AUTOPILOT_RTL,
        HlcEvent.LOW_BATTERY,
        HlcEvent.ALTITUDE_REACHED,
    }
)
#: id(table) -> (the table, kept so that its id is never another's; its deaf states).
_DEAF: dict[int, tuple[object, frozenset[HlcState]]] = {}


def _deaf_states(table: Table[HlcState, HlcEvent, HlcView, HlcRow]) -> frozenset[HlcState]:
    """The states of ``table`` in which a snapshot with a fresh link makes no event a row takes: not
    INIT and LLC_DOWN (they read the vehicle to leave), nor any state taking one of `_FROM_SNAPSHOT`.
    Worked out once per table (the machines of a process share it)."""
    known = _DEAF.get(id(table))
    if known is not None and known[0] is table:
        return known[1]
    deaf = frozenset(
        state
        for state in HlcState
        if state not in (HlcState.INIT, HlcState.LLC_DOWN) and not table.events_taken(state) & _FROM_SNAPSHOT
    )
    _DEAF[id(table)] = (table, deaf)
    return deaf


#: Per state, whether some row takes (LANDED, PILOT_TAKEOVER, AUTOPILOT_LAND, AUTOPILOT_RTL,
#: LOW_BATTERY, ALTITUDE_REACHED): what `_vehicle_events` asks on every snapshot of a flight, where a
#: set's ``in`` would hash the `HlcEvent` in Python (``Enum.__hash__``, ~150 ns each).
_Takes = tuple[bool, bool, bool, bool, bool, bool]
#: id(table) -> (the table, as in `_DEAF`; its `_Takes` per state).
_TAKES: dict[int, tuple[object, dict[HlcState, _Takes]]] = {}


def _takes_by_state(table: Table[HlcState, HlcEvent, HlcView, HlcRow]) -> dict[HlcState, _Takes]:
    """`_Takes` of every state of ``table``, worked out once per table."""
    known = _TAKES.get(id(table))
    if known is not None and known[0] is table:
        return known[1]
    events = (
        _E_LANDED,
        _E_PILOT_TAKEOVER,
        _E_AUTOPILOT_LAND,
        _E_AUTOPILOT_RTL,
        _E_LOW_BATTERY,
        _E_ALTITUDE_REACHED,
    )
    by_state: dict[HlcState, _Takes] = {}
    for state in HlcState:
        taken = table.events_taken(state)
        a, b, c, d, e, f = (event in taken for event in events)
        by_state[state] = (a, b, c, d, e, f)
    _TAKES[id(table)] = (table, by_state)
    return by_state


class HighLevelControl:
    """The HLC machine. Read `state`; feed observations; perform the returned actions."""

    # Slots: a thousand machines in a process are read on every control tick, each out of the
    # cache by then; a slot is read at its offset, where a dict of its own is a hash lookup.
    __slots__ = (
        "params",
        "_table",
        "state",
        "entered_at",
        "mc_state",
        "vehicle",
        "mc_state_at_entry",
        "low_battery_handled",
        "mc_moved",
        "reason",
        "_mc_takeoff_altitude",
        "_target_altitude",
        "_deaf",
        "_takes",
    )

    if not TYPE_CHECKING:  # the old names, one release (issue #26's vocabulary); mypy sees only the new
        autopilot = renamed_attribute("vehicle")
        on_autopilot = renamed_attribute("on_vehicle")

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
        self.vehicle: VehicleState | None = None  # the last snapshot of the vehicle
        self.mc_state_at_entry: int | None = None  # the MC's state when `state` began
        self.low_battery_handled = False  # LOW_BATTERY was entered since the last READY
        self.mc_moved = False  # the MC has been in another state than `mc_state_at_entry` since
        self.reason = "waiting for the autopilot and the MC"  # why the HLC is in `state` (hlc_state_t.reason)
        self._mc_takeoff_altitude = 0.0
        self._target_altitude = 0.0
        #: The states in which no row takes an event a fresh snapshot can make (`_deaf_states`).
        self._deaf = _deaf_states(table)
        #: What the rows of each state take of the snapshot's events (`_takes_by_state`).
        self._takes = _takes_by_state(table)

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
        ap, p = self.vehicle, self.params
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

    def on_vehicle(self, snapshot: VehicleState, now: float, *, fault: str = "") -> HlcOutcome:
        """A snapshot of the vehicle (the node polls `VehicleAdapter.state()`).

        `fault` says why the snapshot is not fresh when the node knows (``state()`` raised: the node
        passes the last good snapshot with its `link_age` grown); it goes into the LLC_DOWN reason.
        """
        self.vehicle = snapshot
        if self.state in self._deaf and snapshot.link_age < self.params.link_timeout:
            # A fresh snapshot in a state with no row for anything a snapshot says (READY, the
            # MC's STANDBY: most of a swarm's life, 20 times a second per agent): nothing to derive.
            return NOTHING
        events = self._vehicle_events(snapshot, fault)
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
        if self.state is not _S_GAINING_ALTITUDE:
            return NOTHING  # 20 a second per agent, nearly always in another state
        timeout = self.params.gain_altitude_timeout
        if self.entered_at is not None and now - self.entered_at >= timeout:
            detail = f"still below {self.params.airborne_fraction:g} x {self._target_altitude:g} m after {timeout:g} s"
            return self._fire([(HlcEvent.GAIN_ALTITUDE_TIMEOUT, detail)], now)
        return NOTHING

    # ----------------------------------------------------------------- event derivation

    def _takeoff_detail(self) -> str:
        ap = self.vehicle
        battery = f"{ap.battery:.1f}%" if ap is not None and ap.battery_known else "unknown"
        low = self.battery_low_reason()
        return f"MC TAKEOFF to {self._requested_altitude():g} m, " + (
            low or f"battery {battery} (low_battery {self.params.low_battery:g}%)"
        )

    def _link_fresh(self, ap: VehicleState) -> bool:
        return ap.connected and ap.link_age < self.params.link_timeout

    def _init_events(self) -> list[tuple[HlcEvent, str]]:
        ap = self.vehicle
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

    def _regained_events(self, ap: VehicleState) -> list[tuple[HlcEvent, str]]:
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
    def _vehicle_detail(ap: VehicleState) -> str:
        failsafe = f", failsafe: {ap.failsafe}" if ap.failsafe else ""
        return f"vehicle armed and in air, mode {ap.mode or '?'} at {ap.alt:.1f} m{failsafe}"

    def _vehicle_events(self, ap: VehicleState, fault: str = "") -> list[tuple[HlcEvent, str]]:
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
        landed, pilot, autopilot_land, autopilot_rtl, low_battery, altitude = self._takes[self.state]
        events: list[tuple[HlcEvent, str]] = []
        if landed and not ap.in_air and not ap.armed:  # `VehicleState.landed`, inline
            events.append((HlcEvent.LANDED, f"on the ground and disarmed (mode {ap.mode or '?'})"))
        if (
            pilot
            and ap.armed
            and not (ap.autonomous and ap.flight_mode is _F_GUIDED)  # ours: no pilot, no call
            and pilot_in_control(ap)
        ):
            events.append(
                (HlcEvent.PILOT_TAKEOVER, f"autopilot left autonomous control (mode {ap.mode or '?'})")
            )
        if self.state is _S_INIT:
            events.extend(self._init_events())
        if ap.failsafe and ap.flight_mode in FAILSAFE_MODES:
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
        if ap.flight_mode is _F_LANDING and autopilot_land:
            events.append((HlcEvent.AUTOPILOT_LAND, f"autopilot switched to {ap.mode or 'LAND'}"))
        if ap.flight_mode is _F_RTL and autopilot_rtl:
            events.append((HlcEvent.AUTOPILOT_RTL, f"autopilot switched to {ap.mode or 'RTL'}"))
        # Well above every threshold (the flight's every tick), `battery_low_reason` is not asked:
        # a NaN or unknown value, or a voltage at or below the cells' threshold, asks it.
        if low_battery and not (
            ap.battery > p.low_battery
            and not ap.battery_warning
            and not ap.cells * p.low_cell_voltage >= ap.voltage
        ):
            low = self.battery_low_reason()
            if low:
                events.append((HlcEvent.LOW_BATTERY, low))
        if altitude and altitude_reached(ap.alt, self._target_altitude, p.airborne_fraction):
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


__all__ = [
    # defined here
    "HighLevelControl",
    "HlcParams",
    # importable from here as before the split: the table (table.py)
    "HLC_TABLE",
    "HlcRow",
    "HlcView",
    # its events (events.py)
    "HlcEvent",
    "Control",
    "classify",
    "pilot_in_control",
    # what its rows ask of the node (effects.py)
    "Action",
    "ActionKind",
    "ErrorCode",
    "HlcError",
    "HlcOutcome",
    "HlcTransition",
    "NOTHING",
]
