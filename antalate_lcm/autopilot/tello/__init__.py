"""The Tello adapter (``autopilot = "tello"``): `TelloAutopilot` and its parameters.

``adapter`` flies it through a ``link`` (`DjitellopyLink`: djitellopy, an optional extra:
``pip install 'antalate[tello]'``; `MemoryLink`: a peer in this process), built from: ``commands``
(the SDK command path and its waits), ``control`` (the control thread), ``failsafe`` (link loss and
what the vehicle does uncommanded), ``takeoff``, ``rtl`` and ``landing`` (the moves), ``tracking``
(state packets into position and link age) and ``flight`` (the phase), sharing what ``parts``
names. ``telemetry`` reads a state packet into the adapter's units, ``maths`` the frames, dead
reckoning, rc scaling, climb and landing rules, ``params`` the validated ``[hlc.autopilot_params]``.
"""

from antalate_lcm.autopilot.tello.adapter import TelloAutopilot
from antalate_lcm.autopilot.tello.link import (
    DJITELLOPY_MISSING,
    DjitellopyLink,
    LinkOpener,
    MemoryLink,
    TelloLink,
)
from antalate_lcm.autopilot.tello.params import DEFAULTS, TELLO_AUTOLAND_S, Params

__all__ = [
    "DEFAULTS",
    "DJITELLOPY_MISSING",
    "TELLO_AUTOLAND_S",
    "DjitellopyLink",
    "LinkOpener",
    "MemoryLink",
    "Params",
    "TelloAutopilot",
    "TelloLink",
]
