"""The Mission Control state machine (docs/design.md §5) as an explicit transition table.

Pure logic: no I/O, no clock. The MC node feeds it:

* `MissionControl.on_command(command, seq, now, altitude=..., sender=...)` -- an operator command;
* `MissionControl.on_hlc_state(state, now)` -- every ``hlc_state_t`` heard;
* `MissionControl.tick(now)` -- periodically, for the takeoff acknowledgement timeout and the HLC
  watchdog (`McParams.hlc_timeout`).

Every call returns a `McOutcome` so the node can log each transition and each rejection with its
reason, and publish ``mc_state_t`` with `MissionControl.last_command_seq` as the operator's ack.

Commands
--------
A command that has no row in the current state is rejected with a reason and does not touch
`last_command_seq`. A command is a *duplicate* when the same (sender, seq, command) was accepted within
`McParams.duplicate_window` seconds: it is reported as accepted and duplicate, with no transition,
so the operator's resend-until-acknowledged loop is harmless. Keying on the sender as well as the
seq matters because seqs are per-sender counters: two operators (a console and an auto-operator)
will reuse each other's numbers. The window (rather than "seq <= last") lets a restarted operator,
whose counter starts again from zero, be heard.

Rows beyond docs/design.md §5, and why
------------------------------
* INIT + HLC LOW_BATTERY -> RTL: restart resync, like the other INIT rows; a low-battery HLC is
  flying home.
* TAKEOFF/MISSION + HLC RTL -> RTL, MISSION + HLC LANDING -> LAND: the vehicle's own failsafe
  (e.g. ArduCopter's battery or GCS failsafe) is bringing it back or down; behaviors must stop, so
  the mission state follows what the vehicle does.
* MISSION + HLC READY -> STANDBY: the vehicle landed and disarmed on its own (e.g. a Tello's own
  low-battery landing); without it the MC would sit in MISSION on the ground.

Failsafe rows (docs/design.md §5, "failsafes" rows), and the choices behind them
------------------------------------------------------------------------------
* **Link regained** (ERROR + any HLC state but LLC_DOWN): the vehicle is reachable again. On the
  ground (HLC READY) the MC is simply STANDBY. If the vehicle is already doing something on its own
  (HLC RTL, LANDING, MANUAL, LOW_BATTERY) the MC follows it. If it waits for a decision (HLC HOLD, or
  AIRBORNE after an HLC restart) `McParams.on_link_regained` decides: RTL, LAND or HOLD; the reason
  names the policy so the operator knows why the vehicle moves.
* **Operator RTL/LAND in ERROR** are accepted only while the HLC reports a state other than
  LLC_DOWN/INIT (someone can execute them); otherwise the rejection says the autopilot is unreachable.
* **HOLD** (the vehicle stopped and waits: an autopilot fence BRAKE, or the hold policy) accepts
  operator RTL and LAND, and follows whatever the vehicle does next.
* **RTL + operator LAND -> LAND**: landing where it is beats flying home on a failing battery or
  after a failsafe; the HLC follows.
* **HLC watchdog**: no ``hlc_state_t`` for `McParams.hlc_timeout` past INIT -> HLC_LOST. Nobody can
  execute a command then, so HLC_LOST rejects every command with that reason (the vehicle is on its
  own GCS failsafe). When the HLC is heard again the MC resyncs exactly as from INIT (the INIT rows
  apply to HLC_LOST as well): the matching state, no command.
* "Follow the vehicle" rows into HOLD and LAND + HLC RTL fire only on the HLC's *change* of state
  (`MissionControl.hlc_changed`): the HLC republishes its state at 5 Hz, and a republished HOLD that
  was sent before the HLC heard the MC's new RTL must not pull the MC back to HOLD.

The TAKEOFF -> STANDBY rows need to know whether the HLC *left* READY since the command: the HLC
is READY when the command is accepted, so "HLC READY" alone would cancel every takeoff at once.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from antalate_lcm.base.state_machine import Row, Table, Transition
from antalate_lcm.wire.vocabulary import Command, HlcState, McState, member_of


class McEvent(enum.Enum):
    """Inputs of the table: operator commands, HLC states heard, and the takeoff timer."""

    OP_TAKEOFF = "OP_TAKEOFF"
    OP_LAND = "OP_LAND"
    OP_RTL = "OP_RTL"
    HLC_INIT = "HLC_INIT"
    HLC_READY = "HLC_READY"
    HLC_TAKEOFF = "HLC_TAKEOFF"
    HLC_GAINING_ALTITUDE = "HLC_GAINING_ALTITUDE"
    HLC_AIRBORNE = "HLC_AIRBORNE"
    HLC_RTL = "HLC_RTL"
    HLC_LANDING = "HLC_LANDING"
    HLC_MANUAL = "HLC_MANUAL"
    HLC_LOW_BATTERY = "HLC_LOW_BATTERY"
    HLC_LLC_DOWN = "HLC_LLC_DOWN"
    HLC_HOLD = "HLC_HOLD"
    TAKEOFF_ACK_TIMEOUT = "TAKEOFF_ACK_TIMEOUT"
    HLC_TIMEOUT = "HLC_TIMEOUT"  # no hlc_state_t for McParams.hlc_timeout

    # Members are singletons compared by identity: identity's hash (in C) instead of Enum's, which
    # hashes the name in Python on every table lookup (5 HLC states a second per agent).
    __hash__ = object.__hash__

    @classmethod
    def of_command(cls, command: Command) -> McEvent:
        return cls[f"OP_{command.name}"]


#: HLC state -> the event its hlc_state_t is (HLC_<name>).
_OF_HLC = {state: McEvent[f"HLC_{state.name}"] for state in HlcState}
#: Members read per hlc_state_t heard and per tick, bound once (in CPython 3.11 ``McState.TAKEOFF``
#: calls the enum's descriptor, ~125 ns).
_TAKEOFF, _HLC_READY = McState.TAKEOFF, HlcState.READY


@dataclass(frozen=True)
class McParams:
    """MC tunables (the ``[mc]`` config table)."""

    takeoff_ack_timeout: float = 5.0  # s the HLC may stay READY after an accepted TAKEOFF
    duplicate_window: float = 60.0  # s an accepted (sender, seq, command) is remembered
    hlc_timeout: float = 2.0  # s without an hlc_state_t before HLC_LOST
    on_link_regained: str = "rtl"  # rtl | land | hold: what to do when the HLC's link comes back in the air

    def __post_init__(self) -> None:
        for name in ("takeoff_ack_timeout", "duplicate_window", "hlc_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"McParams.{name} must be a positive number, got {value!r}")
        if self.on_link_regained not in LINK_REGAINED_POLICIES:
            raise ValueError(
                f"McParams.on_link_regained must be one of {', '.join(LINK_REGAINED_POLICIES)},"
                f" got {self.on_link_regained!r}"
            )


#: `McParams.on_link_regained` values and the MC state each leads to.
LINK_REGAINED_POLICIES: dict[str, McState] = {"rtl": McState.RTL, "land": McState.LAND, "hold": McState.HOLD}


#: A state change with its cause, for the node's log.
McTransition = Transition[McState, McEvent]


@dataclass(frozen=True)
class McOutcome:
    """What one input did.

    `accepted` is False only for a rejected command or an unintelligible input (the `reason` says
    why); observations that change nothing are accepted with no transition and an empty reason.
    """

    accepted: bool
    transition: McTransition | None = None
    reason: str = ""
    duplicate: bool = False

    @property
    def changed(self) -> bool:
        return self.transition is not None


#: An observation that changed nothing (immutable, so one serves every tick and every republish).
_ACCEPTED = McOutcome(True)


class McView(Protocol):
    """What the MC table's guards may read of the machine (read-only: see `antalate_lcm.base.state_machine`)."""

    @property
    def params(self) -> McParams: ...
    @property
    def hlc_state(self) -> HlcState | None: ...
    @property
    def hlc_changed(self) -> bool: ...
    @property
    def hlc_left_ready(self) -> bool: ...


#: A row of the MC table; `extra` marks one not in docs/design.md §5 (see the module docstring).
McRow = Row[McState, McEvent, McView]
_Guard = Callable[[McView], bool]


def _hlc_left_ready(mc: McView) -> bool:
    return mc.hlc_left_ready


def _hlc_changed(mc: McView) -> bool:
    return mc.hlc_changed


def _hlc_link_up(mc: McView) -> bool:
    return mc.hlc_state not in (None, HlcState.LLC_DOWN, HlcState.INIT)


def _policy(target: McState) -> _Guard:
    def guard(mc: McView) -> bool:
        return LINK_REGAINED_POLICIES[mc.params.on_link_regained] is target

    return guard


def _s(*states: McState) -> frozenset[McState]:
    return frozenset(states)


S = McState
E = McEvent
_RESYNC = frozenset({S.INIT, S.HLC_LOST})  # where the MC takes the HLC's word for what is going on

#: The MC transition table, in priority order (the first row matching state, event and guard wins).
MC_TABLE: Table[McState, McEvent, McView, McRow] = Table(
    (
        McRow(
            frozenset(S) - {S.ERROR},
            E.HLC_LLC_DOWN,
            S.ERROR,
            "HLC lost its autopilot link: the vehicle is on its own failsafe until the link is back",
        ),
        McRow(frozenset(S) - {S.INIT, S.HLC_LOST}, E.HLC_TIMEOUT, S.HLC_LOST, "HLC lost"),
        McRow(_RESYNC, E.HLC_READY, S.STANDBY, "HLC ready"),
        McRow(_RESYNC, E.HLC_GAINING_ALTITUDE, S.TAKEOFF, "restart resync: HLC gaining altitude"),
        McRow(_RESYNC, E.HLC_AIRBORNE, S.MISSION, "restart resync: HLC airborne"),
        McRow(_RESYNC, E.HLC_RTL, S.RTL, "restart resync: HLC returning"),
        McRow(_RESYNC, E.HLC_LANDING, S.LAND, "restart resync: HLC landing"),
        McRow(_RESYNC, E.HLC_MANUAL, S.MANUAL, "restart resync: pilot in control"),
        McRow(_RESYNC, E.HLC_HOLD, S.HOLD, "restart resync: vehicle holding"),
        McRow(_RESYNC, E.HLC_LOW_BATTERY, S.RTL, "restart resync: HLC returning on low battery", extra=True),
        McRow(_s(S.STANDBY), E.OP_TAKEOFF, S.TAKEOFF, "operator TAKEOFF"),
        McRow(_s(S.TAKEOFF), E.HLC_AIRBORNE, S.MISSION, "HLC airborne"),
        McRow(
            _s(S.TAKEOFF), E.HLC_READY, S.STANDBY, "HLC back to READY: takeoff failed", guard=_hlc_left_ready
        ),
        McRow(
            _s(S.TAKEOFF), E.TAKEOFF_ACK_TIMEOUT, S.STANDBY, "HLC never left READY: takeoff not acknowledged"
        ),
        McRow(_s(S.TAKEOFF), E.HLC_LANDING, S.LAND, "HLC landing: altitude not gained"),
        McRow(_s(S.TAKEOFF, S.MISSION, S.RTL, S.HOLD), E.OP_LAND, S.LAND, "operator LAND"),
        McRow(_s(S.TAKEOFF, S.MISSION, S.HOLD), E.OP_RTL, S.RTL, "operator RTL"),
        McRow(
            _s(S.ERROR),
            E.OP_LAND,
            S.LAND,
            "operator LAND with the HLC reporting its link up",
            guard=_hlc_link_up,
        ),
        McRow(
            _s(S.ERROR),
            E.OP_RTL,
            S.RTL,
            "operator RTL with the HLC reporting its link up",
            guard=_hlc_link_up,
        ),
        McRow(_s(S.TAKEOFF, S.MISSION, S.HOLD), E.HLC_LOW_BATTERY, S.RTL, "HLC low battery: returning"),
        McRow(_s(S.RTL, S.HOLD), E.HLC_LANDING, S.LAND, "HLC landing"),
        McRow(_s(S.RTL, S.LAND, S.HOLD), E.HLC_READY, S.STANDBY, "landed and disarmed"),
        McRow(_s(S.TAKEOFF, S.MISSION, S.RTL, S.LAND, S.HOLD), E.HLC_MANUAL, S.MANUAL, "pilot override"),
        McRow(_s(S.MANUAL), E.HLC_READY, S.STANDBY, "pilot landed and disarmed"),
        McRow(_s(S.TAKEOFF, S.MISSION), E.HLC_RTL, S.RTL, "vehicle returning on its own", extra=True),
        McRow(_s(S.MISSION), E.HLC_LANDING, S.LAND, "vehicle landing on its own", extra=True),
        McRow(_s(S.MISSION), E.HLC_READY, S.STANDBY, "vehicle landed on its own", extra=True),
        # The vehicle's own failsafes: follow what it does (never MANUAL for an autopilot's decision).
        McRow(
            _s(S.TAKEOFF, S.MISSION, S.RTL, S.LAND, S.MANUAL),
            E.HLC_HOLD,
            S.HOLD,
            "vehicle holding on its own",
            guard=_hlc_changed,
        ),
        McRow(
            _s(S.LAND, S.MANUAL, S.HOLD), E.HLC_RTL, S.RTL, "vehicle returning on its own", guard=_hlc_changed
        ),
        McRow(_s(S.MANUAL), E.HLC_LANDING, S.LAND, "vehicle landing on its own"),
        # The autopilot link is back (ERROR is only entered on HLC LLC_DOWN).
        McRow(_s(S.ERROR), E.HLC_READY, S.STANDBY, "autopilot link regained, vehicle on the ground"),
        McRow(_s(S.ERROR), E.HLC_RTL, S.RTL, "autopilot link regained, vehicle returning on its own"),
        McRow(_s(S.ERROR), E.HLC_LANDING, S.LAND, "autopilot link regained, vehicle landing on its own"),
        McRow(
            _s(S.ERROR), E.HLC_LOW_BATTERY, S.RTL, "autopilot link regained, vehicle returning on low battery"
        ),
        McRow(_s(S.ERROR), E.HLC_MANUAL, S.MANUAL, "autopilot link regained, pilot in control"),
        *(
            McRow(
                _s(S.ERROR),
                event,
                target,
                f"autopilot link regained in the air: on_link_regained = {policy}",
                guard=_policy(target),
            )
            for event in (E.HLC_HOLD, E.HLC_AIRBORNE)
            for policy, target in LINK_REGAINED_POLICIES.items()
        ),
    )
)
del S, E

#: For rejection messages: in which states each command is accepted.
_ACCEPTED_IN: dict[McEvent, tuple[McState, ...]] = {
    event: tuple(sorted(MC_TABLE.sources_of(event)))
    for event in (McEvent.OP_TAKEOFF, McEvent.OP_LAND, McEvent.OP_RTL)
}


class MissionControl:
    """The MC machine. Read `state`, `last_command_seq`, `takeoff_altitude`; feed it inputs."""

    # Slots, as the HLC's machine: read 10 times a second per agent, out of the cache each time.
    __slots__ = (
        "params",
        "_table",
        "state",
        "entered_at",
        "last_command_seq",
        "takeoff_altitude",
        "hlc_state",
        "hlc_heard_at",
        "hlc_changed",
        "hlc_left_ready",
        "reason",
        "_accepted",
    )

    def __init__(
        self, params: McParams | None = None, *, table: Table[McState, McEvent, McView, McRow] = MC_TABLE
    ) -> None:
        self.params = params or McParams()
        self._table = table
        self.state: McState = McState.INIT
        self.entered_at: float | None = None
        self.last_command_seq: int = 0
        self.takeoff_altitude: float = 0.0  # m requested by the accepted TAKEOFF; 0 = HLC default
        self.hlc_state: HlcState | None = None  # last heard
        self.hlc_heard_at: float | None = None  # `now` of the last hlc_state_t, None = never
        self.hlc_changed = False  # the last hlc_state_t heard differs from the one before
        self.hlc_left_ready = False  # since entering TAKEOFF
        self.reason = "waiting for the HLC"  # why the MC is in `state` (mc_state_t.reason)
        self._accepted: dict[tuple[str, int, Command], float] = {}

    # ----------------------------------------------------------------- inputs

    def on_command(
        self,
        command: Command | int,
        seq: int,
        now: float,
        *,
        altitude: float = 0.0,
        sender: str = "",
    ) -> McOutcome:
        """An operator command (already authenticated by the node). `altitude` is for TAKEOFF only."""
        try:
            cmd = Command(command)
        except ValueError:
            return McOutcome(False, reason=f"unknown operator command {command!r} (seq {seq})")
        label = f"operator {cmd.name} seq {seq}" + (f" from {sender!r}" if sender else "")
        self._forget_old(now)
        key = (sender, seq, cmd)
        if key in self._accepted:
            return McOutcome(
                True, reason=f"{label}: duplicate of an accepted command, ignored", duplicate=True
            )
        if cmd is Command.TAKEOFF and not (math.isfinite(altitude) and altitude >= 0.0):
            return McOutcome(False, reason=f"{label} rejected: altitude {altitude!r} is not a number >= 0")
        event = McEvent.of_command(cmd)
        row = self._table.match(self.state, event, self)
        if row is None:
            allowed = ", ".join(s.name for s in _ACCEPTED_IN[event])
            why = f"accepted in {allowed}"
            if self.state is McState.HLC_LOST:
                why = (
                    f"the HLC is silent: nobody can execute it, the vehicle is on its own GCS failsafe; {why}"
                )
            elif self.state is McState.ERROR and event is not McEvent.OP_TAKEOFF:
                heard = self.hlc_state.name if self.hlc_state is not None else "nothing"
                why = f"the HLC reports {heard}: the autopilot cannot be reached; {why} (ERROR: once the link is up)"
            return McOutcome(False, reason=f"{label} rejected in {self.state.name} ({why})")
        self._accepted[key] = now
        self.last_command_seq = seq
        if cmd is Command.TAKEOFF:
            self.takeoff_altitude = altitude
        detail = f"seq {seq}" + (f" from {sender!r}" if sender else "")
        if cmd is Command.TAKEOFF:
            detail += f", altitude {altitude:g} m" if altitude else ", default altitude"
        transition = self._apply(row, event, detail, now)
        return McOutcome(True, transition, reason=transition.reason)

    def on_hlc_state(self, state: HlcState | int, now: float) -> McOutcome:
        """An ``hlc_state_t`` was heard (republished at 5 Hz: most observations change nothing)."""
        hlc = member_of(HlcState, state)  # a lookup, not the enum's call: per hlc_state_t heard
        if hlc is None:
            return McOutcome(False, reason=f"unknown HLC state {state!r}")
        self.hlc_changed = hlc is not self.hlc_state
        self.hlc_state = hlc
        self.hlc_heard_at = now
        if self.state is _TAKEOFF and hlc is not _HLC_READY:
            self.hlc_left_ready = True
        event = _OF_HLC[hlc]
        row = self._table.match(self.state, event, self)
        if row is None:
            return _ACCEPTED
        transition = self._apply(row, event, f"HLC {hlc.name}", now)
        return McOutcome(True, transition, reason=transition.reason)

    def tick(self, now: float) -> McOutcome:
        """Time passes: fires HLC_TIMEOUT when the HLC fell silent, TAKEOFF_ACK_TIMEOUT when it ignored a TAKEOFF."""
        silent = None if self.hlc_heard_at is None else now - self.hlc_heard_at
        if silent is not None and silent >= self.params.hlc_timeout:
            row = self._table.match(self.state, McEvent.HLC_TIMEOUT, self)
            if row is not None:
                detail = f"HLC silent for {silent:.1f} s; the vehicle is on its own GCS failsafe"
                transition = self._apply(row, McEvent.HLC_TIMEOUT, detail, now)
                return McOutcome(True, transition, reason=transition.reason)
        timeout = self.params.takeoff_ack_timeout
        if (
            self.state is _TAKEOFF
            and not self.hlc_left_ready
            and self.entered_at is not None
            and now - self.entered_at >= timeout
        ):
            row = self._table.match(self.state, McEvent.TAKEOFF_ACK_TIMEOUT, self)
            if row is not None:
                detail = f"HLC still READY after {timeout:g} s"
                transition = self._apply(row, McEvent.TAKEOFF_ACK_TIMEOUT, detail, now)
                return McOutcome(True, transition, reason=transition.reason)
        return _ACCEPTED

    # ----------------------------------------------------------------- the table

    def _apply(self, row: McRow, event: McEvent, detail: str, now: float) -> McTransition:
        target = row.target
        if target is None:  # every MC row changes state (the HLC's table has the rows that stay)
            raise ValueError(f"an MC row must name a target state: {row}")
        transition = McTransition(self.state, target, event, f"{row.why} ({detail})", now)
        self.state = target
        self.reason = transition.reason
        self.entered_at = now
        if target is McState.TAKEOFF:
            # A resync into TAKEOFF comes from an HLC that already left READY.
            self.hlc_left_ready = self.hlc_state not in (None, HlcState.READY)
        return transition

    def _forget_old(self, now: float) -> None:
        horizon = now - self.params.duplicate_window
        for key in [k for k, t in self._accepted.items() if t < horizon]:
            del self._accepted[key]
