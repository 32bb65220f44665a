"""The swarm's geofence mirrored into PX4's own geofence parameters, so it holds if the companion computer dies.

What PX4 v1.15.4 can hold in parameters (src/modules/navigator/geofence_params.c, geofence.h):
``GF_MAX_HOR_DIST`` (m, horizontal distance from home; 0 disables), ``GF_MAX_VER_DIST`` (m above home;
0 disables) and ``GF_ACTION`` (0 none, 1 warning, 2 Hold, 3 Return, 4 Terminate, 5 Land). A polygon
is a fence *mission* (MAV_MISSION_TYPE_FENCE), which the adapter does not upload, and PX4 has no
floor parameter. So, as for ArduCopter (`antalate_lcm.vehicles.mavlink.fence_mirror`), the mirror
is the circumscribed cylinder around home -- the circle through the polygon's farthest vertex plus
the margin -- and the ceiling; the floor is the framework's alone (docs/safety.md).

Pure: `fence_parameters`; `mirror` reads the parameters first (PX4's GF_ACTION is an INT32, written
byte-packed once its type is known: `antalate_lcm.vehicles.px4.vehicle.encode_param`), then writes
and reads them back through the shared `antalate_lcm.vehicles.mavlink.fence_mirror.mirror`.
"""

from __future__ import annotations

import math

from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.vehicles.mavlink import fence_mirror as ardupilot

#: GF_ACTION per [safety.fence] outside policy (geofence_params.c).
ACTIONS = {"return": 3, "land": 5, "hover": 2}
#: The limits first, the action last: no action armed on a half-written fence.
ORDER = ("GF_MAX_HOR_DIST", "GF_MAX_VER_DIST", "GF_ACTION")


def fence_parameters(fence: Geofence, home: tuple[float, float], outside: str = "return") -> dict[str, float]:
    """The GF_* values for `fence` seen from `home` (north, east m in the fence's frame)."""
    radius = max(math.hypot(n - home[0], e - home[1]) for n, e in fence.polygon)
    return {
        "GF_MAX_HOR_DIST": round(radius + fence.margin, 1),
        "GF_MAX_VER_DIST": float(fence.ceiling),
        "GF_ACTION": float(ACTIONS[outside]),
    }


def mirror(link: ardupilot.ParamLink, wanted: dict[str, float]) -> list[str]:
    """Read (the parameters' types), write `wanted` in `ORDER`, read back; the mismatches ([] = held)."""
    link.read_params(list(ORDER))
    return ardupilot.mirror(link, wanted, ORDER)
