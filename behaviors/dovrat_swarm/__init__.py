"""The AntAlate paper's template swarm algorithm: ``logic`` is the pure rule, ``behavior`` its I/O."""

from behaviors.dovrat_swarm.logic import (
    Detection,
    DetectionTracker,
    OperatorDirection,
    SwarmCommand,
    SwarmParams,
    parse_detection_payload,
    swarm_command,
    turn_rate,
)

__all__ = [
    "Detection",
    "DetectionTracker",
    "OperatorDirection",
    "SwarmCommand",
    "SwarmParams",
    "parse_detection_payload",
    "swarm_command",
    "turn_rate",
]
