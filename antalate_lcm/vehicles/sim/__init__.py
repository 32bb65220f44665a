"""The ``sim`` vehicle: an in-process kinematic quadcopter, the default (docs/design.md §7).

It is meant for running the whole framework (and swarms of 200 agents) on one laptop, and for
testing the HLC against faults that are hard to provoke on real hardware. One vehicle, in layers,
each a module:

* `params` -- ``[hlc.autopilot_params]`` (`Params`, `DEFAULTS`);
* `physics` -- `Quadcopter`: the kinematic model and its lazy integration over simulated time
  (docs/simulator.md spells out the dynamics);
* `telemetry` -- `snapshot`: the `VehicleState` it reports, battery voltage and warning included;
* `faults` -- `FaultInjection`: link loss, autopilot failsafes, a pilot taking over, a raising
  ``state()``, at once by method or scheduled by params;
* `persistence` -- `StateFile`: the vehicle outlives a restart of the process that flies it;
* `adapter` -- `SimAdapter`, the `VehicleAdapter` contract over them (``autopilot = "sim"``).
"""

from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.sim.adapter import SimAdapter
from antalate_lcm.vehicles.sim.faults import FAILSAFE_MODES
from antalate_lcm.vehicles.sim.params import DEFAULTS, Params

__all__ = ["DEFAULTS", "FAILSAFE_MODES", "Params", "SimAdapter"]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
