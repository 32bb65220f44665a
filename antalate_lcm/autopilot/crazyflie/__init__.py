"""The Crazyflie adapter (``autopilot = "crazyflie"``): `CrazyflieAutopilot` and its parameters.

``adapter`` does the I/O through Bitcraze's cflib (an optional extra: ``pip install
'antalate[crazyflie]'``); ``frames`` maps the local positioning frame to WGS84, ``telemetry``
decodes the log blocks and the supervisor's bits, ``setpoints`` builds velocity set-points, and
``params`` validates ``[hlc.autopilot_params]``. Only ``adapter.connect`` imports cflib, so a config
naming this adapter validates without it.
"""

from antalate_lcm.autopilot.crazyflie.adapter import CFLIB_MISSING, CrazyflieAutopilot
from antalate_lcm.autopilot.crazyflie.params import DEFAULTS, Params

__all__ = ["CFLIB_MISSING", "DEFAULTS", "CrazyflieAutopilot", "Params"]
