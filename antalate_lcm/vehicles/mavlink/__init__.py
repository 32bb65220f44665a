"""The ``mavlink`` autopilot adapter (ArduCopter through pymavlink), split by job:

* `adapter` -- `MavlinkAdapter`: the HLC's verbs (arm, take-off, modes, velocities, the state);
* `commands` -- COMMAND_LONG and its ACK, confirmed mode changes, parameters, the pre-flight check;
* `connection` -- the link, the receive and transmit threads, the vehicle's picture, the velocity resend;
* `link` -- the I/O: `MavLink`, pymavlink's connection (`PymavlinkLink`) and `MemoryLink` for tests;
* `dialect` -- ArduCopter's mode numbers, names and the messages sent (pure);
* `vehicle` -- the vehicle's picture from its telemetry, COMMAND_ACK matching (pure);
* `setpoints` -- when a velocity set-point may go out, and its resend (pure);
* `streams` -- the telemetry requests, one at a time (pure);
* `params` -- the validated ``[hlc.autopilot_params]``;
* `failsafe` -- who changed the mode: a pilot or one of ArduCopter's failsafes (pure);
* `vehicle_checks` -- the vehicle's own failsafe parameters, checked before flight (pure);
* `signing` -- the MAVLink 2 signing key.

The entry point ``antalate_lcm.vehicles.mavlink:MavlinkAdapter`` stays as it was.
"""

from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.mavlink.adapter import (
    COPTER_MODES,
    DEFAULTS,
    FLIGHT_MODES,
    VELOCITY_TYPE_MASK,
    LinkOpener,
    MavlinkAdapter,
    Params,
    mode_name,
)
from antalate_lcm.vehicles.mavlink.link import MavLink, MemoryLink, PymavlinkLink

__all__ = [
    "COPTER_MODES",
    "DEFAULTS",
    "FLIGHT_MODES",
    "VELOCITY_TYPE_MASK",
    "LinkOpener",
    "MavLink",
    "MavlinkAdapter",
    "MemoryLink",
    "Params",
    "PymavlinkLink",
    "mode_name",
]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
