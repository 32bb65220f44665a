"""Mission Control: the pure state machine (`machine`); the node that wires it to the bus lives beside it.

Its states and commands are wire vocabulary: `antalate_lcm.wire.vocabulary` (`McState`, `Command`).
"""

from antalate_lcm.agent.mc.machine import (
    MC_TABLE,
    McEvent,
    McOutcome,
    McParams,
    McRow,
    McTransition,
    MissionControl,
)

__all__ = [
    "MC_TABLE",
    "McEvent",
    "McOutcome",
    "McParams",
    "McRow",
    "McTransition",
    "MissionControl",
]
