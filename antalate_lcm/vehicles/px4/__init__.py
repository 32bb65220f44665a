"""The ``px4`` vehicle adapter: PX4 through the MAVLink adapter's link, threads and rules, split by job:

* `adapter` -- `Px4Adapter`: PX4's commands, the OFFBOARD hand-over, the vehicle checks;
* `modes` -- PX4's (main, sub) modes, their names and what they mean to the HLC (pure);
* `vehicle` -- `Px4Vehicle`: PX4's readiness, mode ownership and failsafe flag (pure);
* `offboard` -- when a set-point is streamed and when OFFBOARD is asked for (pure);
* `failsafe` -- which PX4 failsafe switched the mode (pure);
* `vehicle_checks` -- PX4's failsafe parameters, checked before flight (pure);
* `params` -- the validated ``[hlc.autopilot_params]``.

Shared MAVLink code (link, signing, streams, acknowledgements) stays in `antalate_lcm.vehicles.mavlink`.
"""

from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.px4.adapter import Px4Adapter
from antalate_lcm.vehicles.px4.params import PX4_DEFAULTS, Px4Params

__all__ = ["PX4_DEFAULTS", "Px4Adapter", "Px4Params"]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
