"""One Tello state packet as the adapter's units and frame: pure, so its conversions test without a Tello.

The packet's ground velocities ``vgx/vgy`` (dm/s, signs and frame as configured) become north/east
m/s through ``home_heading``; ``vgz`` (dm/s, positive down) becomes m/s down; the height is ``h``
(cm, decimetre steps) or the ``tof`` range finder less its ground reading. A field the packet lacks
keeps its previous value (`StateReading` before it), so a partial packet never reads as zero.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from antalate_lcm.vehicles.tello import maths
from antalate_lcm.vehicles.tello.params import Params

TOF_GROUND_CM = 10  # the range finder reads this on the ground
TOF_INVALID_CM = 6000  # and implausibly large values out of range


@dataclass(frozen=True)
class StateReading:
    """What one packet says, in the adapter's units."""

    yaw: float = 0.0  # deg, the Tello's own (0 at power-on)
    vn: float = 0.0  # m/s north
    ve: float = 0.0  # m/s east
    vd: float = 0.0  # m/s down
    h_cm: int = 0  # the raw height, the in-air test
    height: float = 0.0  # m above the take-off point, never below zero
    battery: float = -1.0  # percent; -1 before a packet carried it


def read(raw: Mapping[str, Any], p: Params, home_heading: float, before: StateReading) -> StateReading:
    """The packet `raw` (djitellopy's parsed dict) as a `StateReading`; missing fields from `before`."""
    yaw = float(raw.get("yaw", before.yaw))
    gx = p.vgx_sign * float(raw.get("vgx", 0)) / 10.0
    gy = p.vgy_sign * float(raw.get("vgy", 0)) / 10.0
    if p.velocity_frame == "body":
        gx, gy = maths.body_to_ground(gx, gy, yaw)
    vn, ve = maths.ground_to_ne(gx, gy, home_heading)
    h_cm = int(raw.get("h", before.h_cm))
    height = h_cm / 100.0
    if p.altitude_source == "tof":
        tof = int(raw.get("tof", 0))
        if 0 < tof < TOF_INVALID_CM:
            height = (tof - TOF_GROUND_CM) / 100.0
    return StateReading(
        yaw=yaw,
        vn=vn,
        ve=ve,
        vd=float(raw.get("vgz", 0)) / 10.0,
        h_cm=h_cm,
        height=max(0.0, height),
        battery=float(raw["bat"]) if "bat" in raw else before.battery,
    )
