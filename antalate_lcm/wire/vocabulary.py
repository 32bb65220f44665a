"""The wire vocabulary: the states, commands and severities that travel in the messages, one name each.

Every value here is one of the generated types' constants (``mc_state_t``, ``hlc_state_t``,
``operator_cmd_t``, ``hlc_error_t``), so the ``.lcm`` files stay the only source of the numbers;
``tests/wire/test_vocabulary.py`` fails when a constant is added there and not here (or the reverse),
and when the name literals below (the station's JSON) disagree with the enums.

It lives below every machine and node (docs/architecture.md, "Layers"): the MC machine, the HLC
machine, the BMA, the OSC, the station, the analysis and the console all name a state the same
way, and none of them has to import another to do so.
"""

from __future__ import annotations

import enum
from typing import Literal, TypeVar

from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t, operator_cmd_t


class McState(enum.IntEnum):
    """Mission Control states (``mc_state_t.state``, docs/design.md §5)."""

    INIT = mc_state_t.INIT
    STANDBY = mc_state_t.STANDBY
    TAKEOFF = mc_state_t.TAKEOFF
    MISSION = mc_state_t.MISSION
    RTL = mc_state_t.RTL
    LAND = mc_state_t.LAND
    MANUAL = mc_state_t.MANUAL
    ERROR = mc_state_t.ERROR
    HOLD = mc_state_t.HOLD
    HLC_LOST = mc_state_t.HLC_LOST


class HlcState(enum.IntEnum):
    """High-Level Control states (``hlc_state_t.state``, docs/design.md §6)."""

    INIT = hlc_state_t.INIT
    READY = hlc_state_t.READY
    TAKEOFF = hlc_state_t.TAKEOFF
    GAINING_ALTITUDE = hlc_state_t.GAINING_ALTITUDE
    AIRBORNE = hlc_state_t.AIRBORNE
    RTL = hlc_state_t.RTL
    LANDING = hlc_state_t.LANDING
    MANUAL = hlc_state_t.MANUAL
    LOW_BATTERY = hlc_state_t.LOW_BATTERY
    LLC_DOWN = hlc_state_t.LLC_DOWN
    HOLD = hlc_state_t.HOLD


class Command(enum.IntEnum):
    """Operator commands (``operator_cmd_t.command``).

    Not ``OperatorCommand``: that is the station's JSON model of a whole command
    (`antalate_lcm.station.OperatorCommand`), which carries one of these by name.
    """

    TAKEOFF = operator_cmd_t.TAKEOFF
    LAND = operator_cmd_t.LAND
    RTL = operator_cmd_t.RTL


class Severity(enum.IntEnum):
    """How bad an event is: ``hlc_error_t.severity``, and the console's event log uses the same scale."""

    INFO = hlc_error_t.INFO
    WARNING = hlc_error_t.WARNING
    ERROR = hlc_error_t.ERROR
    CRITICAL = hlc_error_t.CRITICAL


#: The names as the station's JSON spells them; `typing.Literal` so pydantic and mypy check them
#: (a Literal cannot be computed from an enum; the test keeps both equal).
McStateName = Literal[
    "INIT", "STANDBY", "TAKEOFF", "MISSION", "RTL", "LAND", "MANUAL", "ERROR", "HOLD", "HLC_LOST"
]
HlcStateName = Literal[
    "INIT",
    "READY",
    "TAKEOFF",
    "GAINING_ALTITUDE",
    "AIRBORNE",
    "RTL",
    "LANDING",
    "MANUAL",
    "LOW_BATTERY",
    "LLC_DOWN",
    "HOLD",
]
CommandName = Literal["TAKEOFF", "LAND", "RTL"]


K = TypeVar("K", bound=enum.IntEnum)

#: Per enum, its members by wire value: a state message's value is looked up 5 times a second per
#: agent (the BMA, the scripted operator), where the enum's own call costs several dict lookups more.
_MEMBERS: dict[type[enum.IntEnum], dict[object, enum.IntEnum]] = {}


def member_of(kind: type[K], value: object) -> K | None:
    """The member of ``kind`` for a wire value (``kind(value)``); None for a value the contract does
    not define (a newer agent, a corrupt message) and for None (nothing heard yet)."""
    members = _MEMBERS.get(kind)
    if members is None:
        members = _MEMBERS[kind] = {member.value: member for member in kind}
    try:
        return members.get(value)  # type: ignore[return-value]  # the members of ``kind``
    except TypeError:  # unhashable: no wire value
        return None


def name_of(kind: type[enum.IntEnum], value: int | None) -> str | None:
    """The name of a wire value of ``kind`` (e.g. ``name_of(McState, 3) == "MISSION"``).

    None for a value the contract does not define (a newer agent, a corrupt message) and for None
    (nothing heard yet): callers decide whether to refuse it (the BMA, the station's JSON) or show
    the number (logs, the console), and never crash on it.
    """
    member = member_of(kind, value)
    return None if member is None else member.name


def names(kind: type[enum.IntEnum]) -> tuple[str, ...]:
    """Every name of ``kind``, in wire-value order (for messages listing what is allowed)."""
    return tuple(member.name for member in sorted(kind))


__all__ = [
    "Command",
    "CommandName",
    "HlcState",
    "HlcStateName",
    "McState",
    "McStateName",
    "Severity",
    "member_of",
    "name_of",
    "names",
]
