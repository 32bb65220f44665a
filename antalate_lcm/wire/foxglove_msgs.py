"""Foxglove's well-known messages made from antalate's, as JSON: what makes Foxglove's Map, 3D and Log
panels show a swarm with no configuration (each panel looks for its schema by name).

Field names and meanings follow Foxglove's published schemas (foxglove-sdk 0.30's ``foxglove.messages``
docstrings; the ``@foxglove/schemas`` package): ``foxglove.LocationFix``, ``foxglove.SceneUpdate``,
``foxglove.Log``. Only the fields antalate fills are in the JSON Schemas below, each with the type
Foxglove gives it; a time is ``{"sec", "nsec"}`` as in every JSON-encoded Foxglove message. Pure: the
positions, states and clocks come in as arguments.
"""

from __future__ import annotations

import math
from typing import Any

from antalate_lcm.wire.vocabulary import McState

LOCATION_FIX = "foxglove.LocationFix"
SCENE_UPDATE = "foxglove.SceneUpdate"
LOG = "foxglove.Log"

#: The 3D panel's frame: east, north, up in metres from the first position heard (a flight spans a
#: few hundred metres, where the flat-earth frame of ``geo.FlatFrame`` is exact enough to look at).
SCENE_FRAME = "swarm"
#: An agent not heard for this long disappears from the 3D view (Foxglove drops an expired entity).
ENTITY_LIFETIME_S = 3

_NUMBER = {"type": "number"}
_TIME = {
    "type": "object",
    "title": "time",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
    "required": ["sec", "nsec"],
}
_VECTOR3 = {"type": "object", "properties": {k: _NUMBER for k in "xyz"}, "required": list("xyz")}
_QUATERNION = {"type": "object", "properties": {k: _NUMBER for k in "xyzw"}, "required": list("xyzw")}
_POSE = {
    "type": "object",
    "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
    "required": ["position", "orientation"],
}
_COLOR = {"type": "object", "properties": {k: _NUMBER for k in "rgba"}, "required": list("rgba")}


def _object(title: str, description: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": list(properties),
    }


LOCATION_FIX_SCHEMA = _object(
    LOCATION_FIX,
    "A navigation satellite fix: an agent's position from its telemetry_t (Map panel)",
    {
        "timestamp": _TIME,
        "frame_id": {"type": "string", "description": "the agent's name"},
        "latitude": {"type": "number", "description": "Latitude in degrees"},
        "longitude": {"type": "number", "description": "Longitude in degrees"},
        "altitude": {"type": "number", "description": "Altitude in meters (antalate: above home)"},
        "position_covariance": {"type": "array", "items": _NUMBER, "minItems": 9, "maxItems": 9},
        "position_covariance_type": {"type": "integer", "minimum": 0, "maximum": 3},
    },
)

_ARROW = _object(
    "foxglove.ArrowPrimitive",
    "An arrow along the pose's +x axis: the agent's heading",
    {
        "pose": _POSE,
        "shaft_length": _NUMBER,
        "shaft_diameter": _NUMBER,
        "head_length": _NUMBER,
        "head_diameter": _NUMBER,
        "color": _COLOR,
    },
)
_CUBE = _object("foxglove.CubePrimitive", "The agent", {"pose": _POSE, "size": _VECTOR3, "color": _COLOR})
_TEXT = _object(
    "foxglove.TextPrimitive",
    "The agent's name, MC state and battery",
    {
        "pose": _POSE,
        "billboard": {"type": "boolean"},
        "font_size": _NUMBER,
        "scale_invisible": {"type": "boolean"},
        "color": _COLOR,
        "text": {"type": "string"},
    },
)
_KEY_VALUE = _object("foxglove.KeyValuePair", "", {"key": {"type": "string"}, "value": {"type": "string"}})
_EMPTY_LIST = {"type": "array", "maxItems": 0}
_ENTITY = _object(
    "foxglove.SceneEntity",
    "One agent in the 3D view, replaced by the next one with its id",
    {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "id": {"type": "string", "description": "the agent's name"},
        "lifetime": _TIME,
        "frame_locked": {"type": "boolean"},
        "metadata": {"type": "array", "items": _KEY_VALUE},
        "arrows": {"type": "array", "items": _ARROW},
        "cubes": {"type": "array", "items": _CUBE},
        "spheres": _EMPTY_LIST,
        "cylinders": _EMPTY_LIST,
        "lines": _EMPTY_LIST,
        "triangles": _EMPTY_LIST,
        "texts": {"type": "array", "items": _TEXT},
        "models": _EMPTY_LIST,
    },
)
SCENE_UPDATE_SCHEMA = _object(
    SCENE_UPDATE,
    "Agents in the 3D view: east, north, up metres from the first position heard (frame 'swarm')",
    {"deletions": _EMPTY_LIST, "entities": {"type": "array", "items": _ENTITY}},
)

LOG_SCHEMA = _object(
    LOG,
    "An hlc_error_t for the Log panel",
    {
        "timestamp": _TIME,
        "level": {"type": "integer", "minimum": 0, "maximum": 5, "description": "1 DEBUG ... 5 FATAL"},
        "message": {"type": "string"},
        "name": {"type": "string", "description": "the agent's name"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
    },
)

SCHEMAS: dict[str, dict[str, Any]] = {
    LOCATION_FIX: LOCATION_FIX_SCHEMA,
    SCENE_UPDATE: SCENE_UPDATE_SCHEMA,
    LOG: LOG_SCHEMA,
}

#: hlc_error_t severity (INFO, WARNING, ERROR, CRITICAL) -> foxglove.Log level (INFO .. FATAL).
LOG_LEVELS = {0: 2, 1: 3, 2: 4, 3: 5}

#: The agent's cube colour by MC state: the same reading as the console's (calm on the ground, green
#: in the mission, amber on the way home, red for trouble); grey before any state is heard.
_STATE_RGB: dict[int, tuple[float, float, float]] = {
    McState.STANDBY: (0.4, 0.6, 0.9),
    McState.TAKEOFF: (0.3, 0.8, 0.8),
    McState.MISSION: (0.2, 0.8, 0.2),
    McState.RTL: (1.0, 0.65, 0.0),
    McState.LAND: (1.0, 0.85, 0.2),
    McState.HOLD: (0.8, 0.5, 1.0),
    McState.MANUAL: (0.9, 0.9, 0.9),
    McState.ERROR: (0.9, 0.1, 0.1),
    McState.HLC_LOST: (0.9, 0.1, 0.1),
}


def stamp(ns: int) -> dict[str, int]:
    """A Foxglove time from nanoseconds since the epoch (negative clamps to 0: a time is unsigned)."""
    ns = max(0, int(ns))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def location_fix(agent: str, ns: int, lat: float, lon: float, alt: float) -> dict[str, Any]:
    return {
        "timestamp": stamp(ns),
        "frame_id": agent,
        "latitude": lat,
        "longitude": lon,
        "altitude": alt,
        "position_covariance": [0.0] * 9,
        "position_covariance_type": 0,
    }


def _yaw_quaternion(heading_deg: float) -> dict[str, float]:
    """The rotation about up of a heading (clockwise from north) in an east-north-up frame."""
    yaw = math.radians(90.0 - heading_deg) if math.isfinite(heading_deg) else 0.0
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


def scene_update(
    agent: str,
    ns: int,
    east_north_up: tuple[float, float, float],
    heading_deg: float,
    label: str,
    mc_state: int | None,
) -> dict[str, Any]:
    """A SceneUpdate with one entity, the agent: a cube, an arrow along its heading, a label."""
    r, g, b = _STATE_RGB.get(mc_state, (0.6, 0.6, 0.6)) if mc_state is not None else (0.6, 0.6, 0.6)
    x, y, z = east_north_up
    pose = {"position": {"x": x, "y": y, "z": z}, "orientation": _yaw_quaternion(heading_deg)}
    above = {"position": {"x": x, "y": y, "z": z + 1.5}, "orientation": _yaw_quaternion(0.0)}
    color = {"r": r, "g": g, "b": b, "a": 1.0}
    entity = {
        "timestamp": stamp(ns),
        "frame_id": SCENE_FRAME,
        "id": agent,
        "lifetime": {"sec": ENTITY_LIFETIME_S, "nsec": 0},
        "frame_locked": False,
        "metadata": [{"key": "agent", "value": agent}],
        "arrows": [
            {
                "pose": pose,
                "shaft_length": 1.2,
                "shaft_diameter": 0.15,
                "head_length": 0.5,
                "head_diameter": 0.4,
                "color": color,
            }
        ],
        "cubes": [{"pose": pose, "size": {"x": 0.8, "y": 0.8, "z": 0.3}, "color": color}],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [
            {
                "pose": above,
                "billboard": True,
                "font_size": 14.0,
                "scale_invisible": True,
                "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
                "text": label,
            }
        ],
        "models": [],
    }
    return {"deletions": [], "entities": [entity]}


def log_entry(agent: str, ns: int, severity: int, text: str, code: int) -> dict[str, Any]:
    return {
        "timestamp": stamp(ns),
        "level": LOG_LEVELS.get(severity, 4),
        "message": f"[{code}] {text}",
        "name": agent,
        "file": "",
        "line": 0,
    }
