"""High-Level Control: the pure state machine (`machine`) and velocity filter (`velocity_guard`).

Only the machine is re-exported here; import `velocity_guard` from its module. The states and
severities are wire vocabulary: `antalate_lcm.wire.vocabulary` (`HlcState`, `McState`, `Severity`).
"""

from antalate_lcm.agent.hlc.machine import (
    HLC_TABLE,
    Action,
    ActionKind,
    ErrorCode,
    HighLevelControl,
    HlcError,
    HlcEvent,
    HlcOutcome,
    HlcParams,
    HlcRow,
    HlcTransition,
)

__all__ = [
    "HLC_TABLE",
    "Action",
    "ActionKind",
    "ErrorCode",
    "HighLevelControl",
    "HlcError",
    "HlcEvent",
    "HlcOutcome",
    "HlcParams",
    "HlcRow",
    "HlcTransition",
]
