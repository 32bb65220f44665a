"""What the HLC machine asks of its node (docs/design.md §6): the `Action` s to perform on the vehicle
adapter, the ``hlc_error_t`` s to publish (`HlcError`, codes `ErrorCode`), and the `HlcOutcome` of one
input that carries them with the transition, if any. Pure values, shared by the table
(:mod:`antalate_lcm.agent.hlc.table`), the machine and the node."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar

from antalate_lcm.agent.hlc.events import HlcEvent
from antalate_lcm.base.state_machine import Transition
from antalate_lcm.wire.vocabulary import HlcState, Severity


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
    """Autopilot calls the node performs for the machine (`VehicleAdapter` method of the same name)."""

    ARM = "ARM"
    DISARM = "DISARM"
    TAKEOFF = "TAKEOFF"
    LAND = "LAND"
    RTL = "RTL"
    HOVER = "HOVER"  # set_velocity(0, 0, 0, 0, Frame.BODY)


@dataclass(frozen=True)
class Action:
    """One call on the vehicle adapter; `altitude` is only meaningful for TAKEOFF (metres above home)."""

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


__all__ = ["NOTHING", "Action", "ActionKind", "ErrorCode", "HlcError", "HlcOutcome", "HlcTransition"]
