"""The ``mavlink`` autopilot adapter (ArduCopter through pymavlink), split by job:

* `adapter` -- `MavlinkAutopilot`, the link, the threads, the commands;
* `params` -- the validated ``[hlc.autopilot_params]``;
* `failsafe` -- who changed the mode: a pilot or one of ArduCopter's failsafes;
* `vehicle_checks` -- the vehicle's own failsafe parameters, checked before flight;
* `signing` -- the MAVLink 2 signing key.

The entry point ``antalate_lcm.autopilot.mavlink:MavlinkAutopilot`` stays as it was.
"""

from antalate_lcm.autopilot.mavlink.adapter import (
    COPTER_MODES,
    DEFAULTS,
    FLIGHT_MODES,
    VELOCITY_TYPE_MASK,
    MavlinkAutopilot,
    Params,
    mode_name,
)

__all__ = [
    "COPTER_MODES",
    "DEFAULTS",
    "FLIGHT_MODES",
    "VELOCITY_TYPE_MASK",
    "MavlinkAutopilot",
    "Params",
    "mode_name",
]
