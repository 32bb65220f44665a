"""The Crazyflie adapter (``autopilot = "crazyflie"``): `CrazyflieAdapter` and its parameters.

``adapter`` holds the HLC's verbs, ``control`` the control thread (the velocity stream, the
high-level commander's switch, link-loss and battery landings), ``connection`` Bitcraze's cflib link
(an optional extra: ``pip install 'antalate[crazyflie]'``), its log blocks and its reopening;
``modes`` names what the adapter is doing, ``frames`` maps the local positioning frame to WGS84,
``telemetry`` decodes the log blocks and the supervisor's bits, ``setpoints`` builds velocity
set-points, ``memory`` is cflib's ``memory://`` driver, and ``params`` validates
``[hlc.autopilot_params]``. Only ``connect`` imports cflib, so a config naming this adapter validates
without it.
"""

from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.crazyflie.adapter import CFLIB_MISSING, CrazyflieAdapter
from antalate_lcm.vehicles.crazyflie.params import DEFAULTS, Params

__all__ = ["CFLIB_MISSING", "DEFAULTS", "CrazyflieAdapter", "Params"]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
