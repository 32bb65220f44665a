"""The template swarm algorithm of the AntAlate paper (Dovrat & Bruckstein), pure: no I/O, no clock.

The rule: fly forward at a set speed; while a peer is detected in the front sector turn *gently*
one way, while none is turn *sharply* the same way. Its input is one boolean, its output an angular
velocity switching between two values.

Combining it with the operator's direction command (the paper only says the velocity command
"incorporates the operator's direction command with the swarm algorithm's output"): the command is
added as a **drift**, a ground velocity shared by every agent that hears it::

    yaw_rate  = turn_direction * (gentle_turn_rate if detected else sharp_turn_rate)   [deg/s]
    v_body    = (forward_speed, 0)
              + direction_weight * s * (cos(azimuth - heading), sin(azimuth - heading))
    with s    = direction.speed, or forward_speed when the command gives no speed (<= 0)
    then, if max_speed > 0, v_body is scaled down (direction kept) to at most max_speed.

Why a drift and not steering toward the azimuth: the swarm's cohesion comes from the agents'
motion *relative to each other*, and adding the same ground velocity to every agent leaves that
relative motion — and so the swarm rule — untouched (a change of inertial frame). The swarm keeps
its shape and the whole of it translates along the operator's azimuth at ``direction_weight * s``.
Steering each agent's heading instead would fight the turning rule that holds the swarm together.

The output is in the BODY frame (x forward, y right): the forward-plus-turn part needs no heading
at all, so a stale or missing heading only affects the drift, which is then left out.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class SwarmParams(BaseModel):
    """The rule's parameters, validated, since the plugin's ``Params`` are these (one list of names,
    defaults and bounds for the rule and its config)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    #: m/s along the heading.
    forward_speed: float = Field(default=2.0, ge=0, allow_inf_nan=False)
    #: deg/s while a peer is detected in the front sector.
    gentle_turn_rate: float = Field(default=10.0, ge=0, allow_inf_nan=False)
    #: deg/s while no peer is detected.
    sharp_turn_rate: float = Field(default=40.0, ge=0, allow_inf_nan=False)
    #: 1 = turn clockwise (right), -1 = counter-clockwise (both rates turn the same way).
    turn_direction: Literal[1, -1] = 1
    #: Scale of the operator's direction drift; 0 ignores direction commands.
    direction_weight: float = Field(default=1.0, ge=0, allow_inf_nan=False)
    #: Cap on the horizontal speed of the blended command (m/s); 0 = none (the HLC clamps anyway).
    max_speed: float = Field(default=0.0, ge=0, allow_inf_nan=False)


@dataclass(frozen=True)
class OperatorDirection:
    """The fields of ``direction_cmd_t`` that matter here."""

    active: bool
    azimuth: float
    speed: float


@dataclass(frozen=True)
class SwarmCommand:
    """A BODY-frame velocity command: ``vx`` forward, ``vy`` right (m/s), ``yaw_rate`` deg/s clockwise."""

    vx: float
    vy: float
    yaw_rate: float


@dataclass(frozen=True)
class Detection:
    """The fields of ``peer_detection_t`` (also the station's payload JSON)."""

    detected: bool
    count: int = 0
    nearest_range: float = 0.0
    nearest_bearing: float = 0.0


def turn_rate(detected: bool, params: SwarmParams) -> float:
    """The swarm rule itself: gentle while a peer is seen, sharp while none is, always the same way."""
    rate = params.gentle_turn_rate if detected else params.sharp_turn_rate
    return math.copysign(rate, params.turn_direction)


def swarm_command(
    heading: float | None,
    detected: bool,
    direction: OperatorDirection | None,
    params: SwarmParams,
) -> SwarmCommand:
    """The velocity command for one control step (see the module docstring for the formula).

    ``heading`` is degrees from north, clockwise; None when unknown (the drift is then omitted).
    """
    vx, vy = params.forward_speed, 0.0
    if heading is not None and not math.isfinite(heading):
        heading = None
    if direction is not None and not finite_direction(direction):
        direction = None
    if direction is not None and direction.active and heading is not None and params.direction_weight:
        speed = direction.speed if direction.speed > 0 else params.forward_speed
        rel = math.radians(direction.azimuth - heading)
        drift = params.direction_weight * speed
        vx += drift * math.cos(rel)
        vy += drift * math.sin(rel)
    if params.max_speed > 0:
        norm = math.hypot(vx, vy)
        if norm > params.max_speed:
            vx, vy = vx * params.max_speed / norm, vy * params.max_speed / norm
    return SwarmCommand(vx, vy, turn_rate(detected, params))


class DetectionTracker:
    """The latest detection from any source, and whether it is still fresh.

    A detection older than ``timeout`` counts as "no peer": when the sensor or the station goes
    quiet the agent falls back to the sharp turn that searches for peers, rather than trusting a
    stale "peer ahead" and drifting off gently.
    """

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self._latest: Detection | None = None
        self._at = -math.inf

    def update(self, detection: Detection, now: float) -> None:
        self._latest = detection
        self._at = now

    def current(self, now: float) -> Detection | None:
        """The latest detection if fresh, else None."""
        if self._latest is None or now - self._at > self.timeout:
            return None
        return self._latest

    def detected(self, now: float) -> bool:
        current = self.current(now)
        return current is not None and current.detected


def parse_detection_payload(data: bytes) -> Detection | None:
    """The station's operator payload ``{"detected": bool, "count", "nearest_range", "nearest_bearing"}``.

    Returns None for a payload that is not such an object (other applications may use the payload
    topic for other things: those are not errors, only not detections) and for one whose fields
    have the wrong type or are not finite (``Infinity``, ``NaN``, ``"3"``, ``true`` as a count):
    a signed payload proves who sent it, not that it makes sense.
    """
    try:
        obj: Any = json.loads(bytes(data).decode("utf-8"), parse_constant=_no_constant)
    except (UnicodeDecodeError, ValueError):
        return None
    if not isinstance(obj, dict) or not isinstance(obj.get("detected"), bool):
        return None
    count = obj.get("count", 1 if obj["detected"] else 0)
    rng = obj.get("nearest_range", 0.0)
    bearing = obj.get("nearest_bearing", 0.0)
    if not (isinstance(count, int) and not isinstance(count, bool) and 0 <= count <= 1_000_000):
        return None
    if not all(_finite_number(v) for v in (rng, bearing)):
        return None
    return Detection(obj["detected"], count, float(rng), float(bearing))


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def _finite_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def finite_direction(direction: OperatorDirection) -> bool:
    """Whether a direction can enter the arithmetic (the node validates too; this is the rule's own guard)."""
    return math.isfinite(direction.azimuth) and math.isfinite(direction.speed) and direction.speed >= 0
