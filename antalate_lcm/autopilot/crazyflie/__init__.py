"""The Crazyflie adapter (``autopilot = "crazyflie"``): `CrazyflieAutopilot` and its parameters.

``adapter`` holds the HLC's verbs, ``control`` the control thread (the velocity stream, the
high-level commander's switch, link-loss and battery landings), ``connection`` Bitcraze's cflib link
(an optional extra: ``pip install 'antalate[crazyflie]'``), its log blocks and its reopening;
``modes`` names what the adapter is doing, ``frames`` maps the local positioning frame to WGS84,
``telemetry`` decodes the log blocks and the supervisor's bits, ``setpoints`` builds velocity
set-points, ``memory`` is cflib's ``memory://`` driver, and ``params`` validates
``[hlc.autopilot_params]``. Only ``connect`` imports cflib, so a config naming this adapter validates
without it.
"""

from antalate_lcm.autopilot.crazyflie.adapter import CFLIB_MISSING, CrazyflieAutopilot
from antalate_lcm.autopilot.crazyflie.params import DEFAULTS, Params

__all__ = ["CFLIB_MISSING", "DEFAULTS", "CrazyflieAutopilot", "Params"]
