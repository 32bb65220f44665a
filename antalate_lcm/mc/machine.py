"""The Mission Control state machine (docs/design.md §5) as an explicit transition table.

Pure logic: no I/O, no clock. The MC node feeds it:

* `MissionControl.on_command(command, seq, now, altitude=..., sender=...)` -- an operator command;
* `MissionControl.on_hlc_state(state, now)` -- every ``hlc_state_t`` heard;
* `MissionControl.tick(now)` -- periodically, for the takeoff acknowledgement timeout.

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

The TAKEOFF -> STANDBY rows need to know whether the HLC *left* READY since the command: the HLC
is READY when the command is accepted, so "HLC READY" alone would cancel every takeoff at once.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass

from antalate_lcm.hlc.machine import HlcState
from antalate_lcm.msgs import mc_state_t, operator_cmd_t


class McState(enum.IntEnum):
    """MC states; values are the ``mc_state_t`` constants."""

    INIT = mc_state_t.INIT
    STANDBY = mc_state_t.STANDBY
    TAKEOFF = mc_state_t.TAKEOFF
    MISSION = mc_state_t.MISSION
    RTL = mc_state_t.RTL
    LAND = mc_state_t.LAND
    MANUAL = mc_state_t.MANUAL
    ERROR = mc_state_t.ERROR


class OperatorCommand(enum.IntEnum):
    """Operator commands; values are the ``operator_cmd_t`` constants."""

    TAKEOFF = operator_cmd_t.TAKEOFF
    LAND = operator_cmd_t.LAND
    RTL = operator_cmd_t.RTL


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
    TAKEOFF_ACK_TIMEOUT = "TAKEOFF_ACK_TIMEOUT"

    @classmethod
    def of_hlc(cls, state: HlcState) -> McEvent:
        return cls[f"HLC_{state.name}"]

    @classmethod
    def of_command(cls, command: OperatorCommand) -> McEvent:
        return cls[f"OP_{command.name}"]


@dataclass(frozen=True)
class McParams:
    """MC tunables (the ``[mc]`` config table)."""

    takeoff_ack_timeout: float = 5.0  # s the HLC may stay READY after an accepted TAKEOFF
    duplicate_window: float = 60.0  # s an accepted (sender, seq, command) is remembered

    def __post_init__(self) -> None:
        for name in ("takeoff_ack_timeout", "duplicate_window"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"McParams.{name} must be a positive number, got {value!r}")


@dataclass(frozen=True)
class McTransition:
    """A state change with its cause, for the node's log."""

    from_state: McState
    to_state: McState
    event: McEvent
    reason: str
    at: float


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


_Guard = Callable[["MissionControl"], bool]


@dataclass(frozen=True)
class McRow:
    sources: frozenset[McState]
    event: McEvent
    target: McState
    why: str
    guard: _Guard | None = None
    extra: bool = False  # not in docs/design.md §5 (see the module docstring)


def _hlc_left_ready(mc: MissionControl) -> bool:
    return mc.hlc_left_ready


def _s(*states: McState) -> frozenset[McState]:
    return frozenset(states)


S = McState
E = McEvent

#: The MC transition table, in priority order (the first row matching state, event and guard wins).
MC_TABLE: tuple[McRow, ...] = (
    McRow(frozenset(S) - {S.ERROR}, E.HLC_LLC_DOWN, S.ERROR, "HLC lost its autopilot (unrecoverable)"),
    McRow(_s(S.INIT), E.HLC_READY, S.STANDBY, "HLC ready"),
    McRow(_s(S.INIT), E.HLC_GAINING_ALTITUDE, S.TAKEOFF, "restart resync: HLC gaining altitude"),
    McRow(_s(S.INIT), E.HLC_AIRBORNE, S.MISSION, "restart resync: HLC airborne"),
    McRow(_s(S.INIT), E.HLC_RTL, S.RTL, "restart resync: HLC returning"),
    McRow(_s(S.INIT), E.HLC_LANDING, S.LAND, "restart resync: HLC landing"),
    McRow(_s(S.INIT), E.HLC_MANUAL, S.MANUAL, "restart resync: pilot in control"),
    McRow(_s(S.INIT), E.HLC_LOW_BATTERY, S.RTL, "restart resync: HLC returning on low battery", extra=True),
    McRow(_s(S.STANDBY), E.OP_TAKEOFF, S.TAKEOFF, "operator TAKEOFF"),
    McRow(_s(S.TAKEOFF), E.HLC_AIRBORNE, S.MISSION, "HLC airborne"),
    McRow(_s(S.TAKEOFF), E.HLC_READY, S.STANDBY, "HLC back to READY: takeoff failed", guard=_hlc_left_ready),
    McRow(_s(S.TAKEOFF), E.TAKEOFF_ACK_TIMEOUT, S.STANDBY, "HLC never left READY: takeoff not acknowledged"),
    McRow(_s(S.TAKEOFF), E.HLC_LANDING, S.LAND, "HLC landing: altitude not gained"),
    McRow(_s(S.TAKEOFF, S.MISSION), E.OP_LAND, S.LAND, "operator LAND"),
    McRow(_s(S.TAKEOFF, S.MISSION), E.OP_RTL, S.RTL, "operator RTL"),
    McRow(_s(S.TAKEOFF, S.MISSION), E.HLC_LOW_BATTERY, S.RTL, "HLC low battery: returning"),
    McRow(_s(S.RTL), E.HLC_LANDING, S.LAND, "HLC landing"),
    McRow(_s(S.RTL, S.LAND), E.HLC_READY, S.STANDBY, "landed and disarmed"),
    McRow(_s(S.TAKEOFF, S.MISSION, S.RTL, S.LAND), E.HLC_MANUAL, S.MANUAL, "pilot override"),
    McRow(_s(S.MANUAL), E.HLC_READY, S.STANDBY, "pilot landed and disarmed"),
    McRow(_s(S.TAKEOFF, S.MISSION), E.HLC_RTL, S.RTL, "vehicle returning on its own", extra=True),
    McRow(_s(S.MISSION), E.HLC_LANDING, S.LAND, "vehicle landing on its own", extra=True),
    McRow(_s(S.MISSION), E.HLC_READY, S.STANDBY, "vehicle landed on its own", extra=True),
)
del S, E

#: For rejection messages: in which states each command is accepted.
_ACCEPTED_IN: dict[McEvent, tuple[McState, ...]] = {
    event: tuple(sorted({s for row in MC_TABLE if row.event is event for s in row.sources}))
    for event in (McEvent.OP_TAKEOFF, McEvent.OP_LAND, McEvent.OP_RTL)
}


class MissionControl:
    """The MC machine. Read `state`, `last_command_seq`, `takeoff_altitude`; feed it inputs."""

    def __init__(self, params: McParams | None = None, *, table: tuple[McRow, ...] = MC_TABLE) -> None:
        self.params = params or McParams()
        self._table = table
        self.state: McState = McState.INIT
        self.entered_at: float | None = None
        self.last_command_seq: int = 0
        self.takeoff_altitude: float = 0.0  # m requested by the accepted TAKEOFF; 0 = HLC default
        self.hlc_state: HlcState | None = None  # last heard
        self.hlc_left_ready = False  # since entering TAKEOFF
        self._accepted: dict[tuple[str, int, OperatorCommand], float] = {}

    # ----------------------------------------------------------------- inputs

    def on_command(
        self,
        command: OperatorCommand | int,
        seq: int,
        now: float,
        *,
        altitude: float = 0.0,
        sender: str = "",
    ) -> McOutcome:
        """An operator command (already authenticated by the node). `altitude` is for TAKEOFF only."""
        try:
            cmd = OperatorCommand(command)
        except ValueError:
            return McOutcome(False, reason=f"unknown operator command {command!r} (seq {seq})")
        label = f"operator {cmd.name} seq {seq}" + (f" from {sender!r}" if sender else "")
        self._forget_old(now)
        key = (sender, seq, cmd)
        if key in self._accepted:
            return McOutcome(True, reason=f"{label}: duplicate of an accepted command, ignored", duplicate=True)
        if cmd is OperatorCommand.TAKEOFF and not (math.isfinite(altitude) and altitude >= 0.0):
            return McOutcome(False, reason=f"{label} rejected: altitude {altitude!r} is not a number >= 0")
        event = McEvent.of_command(cmd)
        row = self._match(event)
        if row is None:
            allowed = ", ".join(s.name for s in _ACCEPTED_IN[event])
            return McOutcome(False, reason=f"{label} rejected in {self.state.name} (accepted in {allowed})")
        self._accepted[key] = now
        self.last_command_seq = seq
        if cmd is OperatorCommand.TAKEOFF:
            self.takeoff_altitude = altitude
        detail = f"seq {seq}" + (f" from {sender!r}" if sender else "")
        if cmd is OperatorCommand.TAKEOFF:
            detail += f", altitude {altitude:g} m" if altitude else ", default altitude"
        transition = self._apply(row, event, detail, now)
        return McOutcome(True, transition, reason=transition.reason)

    def on_hlc_state(self, state: HlcState | int, now: float) -> McOutcome:
        """An ``hlc_state_t`` was heard (republished at 5 Hz: most observations change nothing)."""
        try:
            hlc = HlcState(state)
        except ValueError:
            return McOutcome(False, reason=f"unknown HLC state {state!r}")
        self.hlc_state = hlc
        if self.state is McState.TAKEOFF and hlc is not HlcState.READY:
            self.hlc_left_ready = True
        event = McEvent.of_hlc(hlc)
        row = self._match(event)
        if row is None:
            return McOutcome(True)
        transition = self._apply(row, event, f"HLC {hlc.name}", now)
        return McOutcome(True, transition, reason=transition.reason)

    def tick(self, now: float) -> McOutcome:
        """Time passes: fires TAKEOFF_ACK_TIMEOUT when the HLC ignored an accepted TAKEOFF."""
        timeout = self.params.takeoff_ack_timeout
        if (
            self.state is McState.TAKEOFF
            and not self.hlc_left_ready
            and self.entered_at is not None
            and now - self.entered_at >= timeout
        ):
            row = self._match(McEvent.TAKEOFF_ACK_TIMEOUT)
            if row is not None:
                detail = f"HLC still READY after {timeout:g} s"
                transition = self._apply(row, McEvent.TAKEOFF_ACK_TIMEOUT, detail, now)
                return McOutcome(True, transition, reason=transition.reason)
        return McOutcome(True)

    # ----------------------------------------------------------------- the table

    def _match(self, event: McEvent) -> McRow | None:
        for row in self._table:
            if row.event is event and self.state in row.sources and (row.guard is None or row.guard(self)):
                return row
        return None

    def _apply(self, row: McRow, event: McEvent, detail: str, now: float) -> McTransition:
        transition = McTransition(self.state, row.target, event, f"{row.why} ({detail})", now)
        self.state = row.target
        self.entered_at = now
        if row.target is McState.TAKEOFF:
            # A resync into TAKEOFF comes from an HLC that already left READY.
            self.hlc_left_ready = self.hlc_state not in (None, HlcState.READY)
        return transition

    def _forget_old(self, now: float) -> None:
        horizon = now - self.params.duplicate_window
        for key in [k for k, t in self._accepted.items() if t < horizon]:
            del self._accepted[key]
