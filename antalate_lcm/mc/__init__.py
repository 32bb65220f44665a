"""Mission Control: the pure state machine (`machine`); the node that wires it to the bus lives beside it."""

from antalate_lcm.mc.machine import (
    MC_TABLE,
    McEvent,
    McOutcome,
    McParams,
    McRow,
    McState,
    McTransition,
    MissionControl,
    OperatorCommand,
)

__all__ = [
    "MC_TABLE",
    "McEvent",
    "McOutcome",
    "McParams",
    "McRow",
    "McState",
    "McTransition",
    "MissionControl",
    "OperatorCommand",
]
