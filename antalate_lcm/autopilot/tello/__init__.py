"""The Tello adapter (``autopilot = "tello"``): `TelloAutopilot` and its parameters.

``adapter`` does the I/O (djitellopy, an optional extra: ``pip install 'antalate[tello]'``; the control thread), ``maths`` the frames, dead reckoning,
rc scaling, climb and landing rules, ``params`` the validated ``[hlc.autopilot_params]``.
"""

from antalate_lcm.autopilot.tello.adapter import DJITELLOPY_MISSING, TelloAutopilot
from antalate_lcm.autopilot.tello.params import DEFAULTS, TELLO_AUTOLAND_S, Params

__all__ = ["DJITELLOPY_MISSING", "DEFAULTS", "TELLO_AUTOLAND_S", "Params", "TelloAutopilot"]
