"""Input validation at the boundary: what a node refuses to hand to its logic, and why.

Every operator command, direction, velocity command and payload a node consumes passes here first
(``Node.subscribe`` calls :func:`problem`), signed or not: a valid MAC proves who sent a message,
not that its numbers make sense, and one infinite azimuth must not reach a behavior's arithmetic.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from antalate_lcm.msgs import direction_cmd_t, operator_cmd_t, payload_t, peer_scan_t, velocity_cmd_t

#: m: a takeoff altitude above this is a typo or an attack (legal ceilings are ~120 m).
MAX_TAKEOFF_ALTITUDE = 1000.0
#: m/s: no multirotor flies a direction faster; the HLC clamps to its own, lower limits anyway.
MAX_DIRECTION_SPEED = 100.0
#: m/s and deg/s: beyond these a velocity command is nonsense, not merely fast (the HLC clamps).
MAX_VELOCITY = 100.0
MAX_YAW_RATE = 3600.0
#: Content types parsed as JSON at the boundary.
JSON_TYPES = frozenset({"application/json", "text/json"})


def _finite(name: str, value: float, low: float, high: float) -> str | None:
    if not math.isfinite(value):
        return f"{name} is {value!r}, not a finite number"
    if not low <= value <= high:
        return f"{name} {value:g} is outside [{low:g}, {high:g}]"
    return None


def _operator_cmd(msg: operator_cmd_t) -> str | None:
    return _finite("altitude", float(msg.altitude), 0.0, MAX_TAKEOFF_ALTITUDE)


def _direction(msg: direction_cmd_t) -> str | None:
    return _finite("azimuth", float(msg.azimuth), -360.0, 360.0) or _finite(
        "speed", float(msg.speed), 0.0, MAX_DIRECTION_SPEED
    )


#: The frames a velocity command may name.
_FRAMES = (velocity_cmd_t.BODY, velocity_cmd_t.NED)


def _velocity(msg: velocity_cmd_t) -> str | None:
    if msg.frame not in _FRAMES:
        return f"frame {msg.frame} is neither BODY nor NED"
    # Every field within its bounds (so finite: NaN fails every comparison), the common case, in
    # one expression (10 Hz per simulated agent); anything else, or a field that is not a number
    # (as ``float`` then, never here), is told by the checks below.
    try:
        if (
            -MAX_VELOCITY <= msg.vx <= MAX_VELOCITY
            and -MAX_VELOCITY <= msg.vy <= MAX_VELOCITY
            and -MAX_VELOCITY <= msg.vz <= MAX_VELOCITY
            and -MAX_YAW_RATE <= msg.yaw_rate <= MAX_YAW_RATE
        ):
            return None
    except TypeError:
        pass
    for name in ("vx", "vy", "vz"):
        problem = _finite(name, float(getattr(msg, name)), -MAX_VELOCITY, MAX_VELOCITY)
        if problem:
            return problem
    return _finite("yaw_rate", float(msg.yaw_rate), -MAX_YAW_RATE, MAX_YAW_RATE)


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON (RFC 8259 has no {name})")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text} overflows a double")
    return value


def strict_json(data: bytes) -> Any:
    """``json.loads`` that refuses ``Infinity``, ``NaN`` and numbers that overflow to them (``1e999``),
    which Python's parser accepts."""
    return json.loads(bytes(data).decode("utf-8"), parse_constant=_reject_constant, parse_float=_finite_float)


def _payload(msg: payload_t) -> str | None:
    if msg.size != len(msg.data):
        return f"size {msg.size} but {len(msg.data)} bytes of data"
    if msg.content_type.split(";", 1)[0].strip().lower() in JSON_TYPES:
        try:
            strict_json(msg.data)
        except (UnicodeDecodeError, ValueError) as exc:
            return f"{msg.content_type} payload is not valid JSON: {exc}"
    return None


#: m: farther than this, a peer "detection" is nonsense (no sensor, no station sector is that big).
MAX_PEER_RANGE = 1e6


def _peer_scan(msg: peer_scan_t) -> str | None:
    problem = _finite("max_range", float(msg.max_range), 0.0, MAX_PEER_RANGE) or _finite(
        "fov", float(msg.fov), 0.0, 360.0
    )
    if problem:
        return problem
    arrays = (msg.range, msg.bearing, msg.elevation, msg.rel_forward, msg.rel_right, msg.id)
    if msg.n < 0 or any(len(a) != msg.n for a in arrays):
        return f"n is {msg.n} but the arrays hold {', '.join(str(len(a)) for a in arrays)} entries"
    for i in range(msg.n):
        problem = (
            _finite(f"range[{i}]", float(msg.range[i]), 0.0, MAX_PEER_RANGE)
            or _finite(f"bearing[{i}]", float(msg.bearing[i]), -180.0, 180.0)
            or _finite(f"elevation[{i}]", float(msg.elevation[i]), -90.0, 90.0)
            or _finite(f"rel_forward[{i}]", float(msg.rel_forward[i]), -MAX_VELOCITY, MAX_VELOCITY)
            or _finite(f"rel_right[{i}]", float(msg.rel_right[i]), -MAX_VELOCITY, MAX_VELOCITY)
        )
        if problem:
            return problem
    return None


_CHECKS: dict[type, Callable[[Any], str | None]] = {
    operator_cmd_t: _operator_cmd,
    direction_cmd_t: _direction,
    velocity_cmd_t: _velocity,
    payload_t: _payload,
    peer_scan_t: _peer_scan,
}


def problem(msg: Any) -> str | None:
    """None if ``msg`` may reach node or behavior logic, else why not (one line, for the log)."""
    check = _CHECKS.get(type(msg))
    return None if check is None else check(msg)


def needs_check(msg_type: type) -> bool:
    """Whether :func:`problem` can find anything in a ``msg_type`` (a subscriber of a type it cannot
    skips the call on every message)."""
    return msg_type in _CHECKS


__all__ = ["MAX_TAKEOFF_ALTITUDE", "needs_check", "problem", "strict_json"]
