"""The ``sim`` vehicle: an in-process kinematic quadcopter, the default (docs/design.md §7).

It is meant for running the whole framework (and swarms of 200 agents) on one laptop, and for
testing the HLC against faults that are hard to provoke on real hardware. One vehicle, in layers,
each a module:

* `params` -- ``[hlc.autopilot_params]`` (`Params`, `DEFAULTS`);
* `physics` -- `Quadcopter`: the kinematic model and its lazy integration over simulated time
  (docs/simulator.md spells out the dynamics);
* `telemetry` -- `snapshot`: the `AutopilotState` it reports, battery voltage and warning included;
* `faults` -- `FaultInjection`: link loss, autopilot failsafes, a pilot taking over, a raising
  ``state()``, at once by method or scheduled by params;
* `persistence` -- `StateFile`: the vehicle outlives a restart of the process that flies it;
* `adapter` -- `SimAutopilot`, the `Autopilot` contract over them (``autopilot = "sim"``).
"""

from antalate_lcm.autopilot.sim.adapter import SimAutopilot
from antalate_lcm.autopilot.sim.faults import FAILSAFE_MODES
from antalate_lcm.autopilot.sim.params import DEFAULTS, Params

__all__ = ["DEFAULTS", "FAILSAFE_MODES", "Params", "SimAutopilot"]
