"""The Tello adapter (``autopilot = "tello"``): `TelloAdapter` and its parameters.

``adapter`` flies it through a ``link`` (`DjitellopyLink`: djitellopy, an optional extra:
``pip install 'antalate[tello]'``; `MemoryLink`: a peer in this process), built from: ``commands``
(the SDK command path and its waits), ``control`` (the control thread), ``failsafe`` (link loss and
what the vehicle does uncommanded), ``takeoff``, ``rtl`` and ``landing`` (the moves), ``tracking``
(state packets into position and link age) and ``flight`` (the phase), sharing what ``parts``
names. ``telemetry`` reads a state packet into the adapter's units, ``maths`` the frames, dead
reckoning, rc scaling, climb and landing rules, ``params`` the validated ``[hlc.autopilot_params]``.
"""

from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.tello.adapter import TelloAdapter
from antalate_lcm.vehicles.tello.link import (
    DJITELLOPY_MISSING,
    DjitellopyLink,
    LinkOpener,
    MemoryLink,
    TelloLink,
)
from antalate_lcm.vehicles.tello.params import DEFAULTS, TELLO_AUTOLAND_S, Params

__all__ = [
    "DEFAULTS",
    "DJITELLOPY_MISSING",
    "TELLO_AUTOLAND_S",
    "DjitellopyLink",
    "LinkOpener",
    "MemoryLink",
    "Params",
    "TelloAdapter",
    "TelloLink",
]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
