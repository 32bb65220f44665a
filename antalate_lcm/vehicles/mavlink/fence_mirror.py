"""The swarm's geofence mirrored into ArduCopter's own fence, so it holds if the companion computer dies.

What ArduPilot can hold in parameters (libraries/AC_Fence/AC_Fence.h and AC_Fence.cpp, ArduPilot 4.x):
``FENCE_ENABLE``; ``FENCE_TYPE``, a bitmask of ALT_MAX 1, CIRCLE 2, POLYGON 4, ALT_MIN 8;
``FENCE_ALT_MAX`` / ``FENCE_ALT_MIN`` (m above home); ``FENCE_RADIUS`` (m, a circle around home);
``FENCE_MARGIN`` (m); ``FENCE_ACTION`` (0 report only, 1 RTL or land, 2 land, 4 brake or land).

The polygon itself is not a parameter: ArduPilot loads it through the MAVLink mission protocol with
``MAV_MISSION_TYPE_FENCE`` items (AC_PolyFence_loader), which the adapter does not speak yet. So the
mirror is the *circumscribed* cylinder: a circle around the vehicle's home through the polygon's
farthest vertex, and the floor and ceiling. It never fires while the framework's fence holds (the
circle contains the polygon), and it stops a vehicle whose companion died before it flies away
(docs/safety.md says what that leaves unguarded: the polygon's corners outside its inscribed circle).

Pure: `fence_parameters` computes them, `mismatches` compares what the vehicle reports; the adapter's
``set_param`` / ``read_params`` do the I/O (`mirror`).
"""

from __future__ import annotations

import math
from typing import Protocol

from antalate_lcm.base.safety.geofence import Geofence

#: FENCE_TYPE bits (AC_Fence.h); POLYGON (4) needs the fence mission protocol, not mirrored here.
ALT_MAX, CIRCLE, ALT_MIN = 1, 2, 8
#: FENCE_ACTION per [safety.fence] outside policy (AC_Fence.h AC_FENCE_ACTION_*).
ACTIONS = {"return": 1, "land": 2, "hover": 4}
#: The order they are written: the limits first, FENCE_ENABLE last (no fence enabled half-set).
ORDER = (
    "FENCE_TYPE",
    "FENCE_ALT_MAX",
    "FENCE_ALT_MIN",
    "FENCE_RADIUS",
    "FENCE_MARGIN",
    "FENCE_ACTION",
    "FENCE_ENABLE",
)


class ParamLink(Protocol):
    """What `mirror` needs of the adapter (`MavlinkAdapter` has both)."""

    def set_param(self, name: str, value: float) -> None: ...

    def read_params(self, names: tuple[str, ...] | list[str]) -> dict[str, float]: ...


def fence_parameters(fence: Geofence, home: tuple[float, float], outside: str = "return") -> dict[str, float]:
    """The FENCE_* values for `fence` seen from `home` (north, east m in the fence's frame)."""
    radius = max(math.hypot(n - home[0], e - home[1]) for n, e in fence.polygon)
    kinds = ALT_MAX | CIRCLE | (ALT_MIN if fence.floor > 0.0 else 0)
    return {
        "FENCE_TYPE": float(kinds),
        "FENCE_ALT_MAX": float(fence.ceiling),
        "FENCE_ALT_MIN": float(fence.floor) if fence.floor > 0.0 else -10.0,
        "FENCE_RADIUS": round(radius + fence.margin, 1),
        "FENCE_MARGIN": float(fence.margin),
        "FENCE_ACTION": float(ACTIONS[outside]),
        "FENCE_ENABLE": 1.0,
    }


def mismatches(wanted: dict[str, float], read: dict[str, float], order: tuple[str, ...] = ORDER) -> list[str]:
    """What the vehicle reports differently from `wanted` (float32 parameters: 1e-3 relative slack)."""
    out = []
    for name in order:
        if name not in wanted:
            continue
        got = read.get(name)
        if got is None:
            out.append(f"{name} not reported")
        elif abs(got - wanted[name]) > 1e-3 * max(1.0, abs(wanted[name])):
            out.append(f"{name} = {got:g}, wanted {wanted[name]:g}")
    return out


def mirror(link: ParamLink, wanted: dict[str, float], order: tuple[str, ...] = ORDER) -> list[str]:
    """Write `wanted` (in `order`), read it all back; the mismatches ([] = the vehicle holds the fence).

    A parameter the firmware does not have (FENCE_ALT_MIN before Copter 4.1) is reported, not fatal:
    the rest of the fence still holds.
    """
    problems = []
    for name in order:
        if name in wanted:
            try:
                link.set_param(name, wanted[name])
            except Exception as exc:  # noqa: BLE001 - AutopilotError, or a link that died meanwhile
                problems.append(f"{name}: {exc}")
    names = [n for n in order if n in wanted]
    problems.extend(
        m
        for m in mismatches(wanted, link.read_params(names), order)
        if not any(m.startswith(p.split(":")[0]) for p in problems)
    )
    return problems
