"""The ``px4`` autopilot adapter: PX4 through the MAVLink adapter's link, threads and rules, split by job:

* `adapter` -- `Px4Autopilot`: PX4's commands, the OFFBOARD hand-over, the vehicle checks;
* `modes` -- PX4's (main, sub) modes, their names and what they mean to the HLC (pure);
* `vehicle` -- `Px4Vehicle`: PX4's readiness, mode ownership and failsafe flag (pure);
* `offboard` -- when a set-point is streamed and when OFFBOARD is asked for (pure);
* `failsafe` -- which PX4 failsafe switched the mode (pure);
* `vehicle_checks` -- PX4's failsafe parameters, checked before flight (pure);
* `params` -- the validated ``[hlc.autopilot_params]``.

Shared MAVLink code (link, signing, streams, acknowledgements) stays in `antalate_lcm.autopilot.mavlink`.
"""

from antalate_lcm.autopilot.px4.adapter import Px4Autopilot
from antalate_lcm.autopilot.px4.params import PX4_DEFAULTS, Px4Params

__all__ = ["PX4_DEFAULTS", "Px4Autopilot", "Px4Params"]
