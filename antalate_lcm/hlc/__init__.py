"""High-Level Control: the pure state machine (`machine`) and velocity filter (`velocity_guard`).

Only the machine is re-exported here; `velocity_guard` depends on the MC states, and importing it
from this package's ``__init__`` would create an import cycle (the MC machine imports `HlcState`).
"""

from antalate_lcm.hlc.machine import (
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
