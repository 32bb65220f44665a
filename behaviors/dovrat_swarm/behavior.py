"""``dovrat_swarm``: the template swarm algorithm wired to topics (the rule is in ``logic.py``).

Inputs, as in the paper's template application: the heading from TELEMETRY, the operator's
direction from DIRECTION_CMD and the broadcast SWARM_DIRECTION_CMD, and peer detection from
PEER_DETECTION (a sensor) and/or OPERATOR_PAYLOAD (the station's JSON answer). Output: a BODY-frame
velocity_cmd_t on VELOCITY_CMD at the tick rate, and one zero command on deactivation so the
vehicle hovers at once instead of waiting for the HLC's command timeout.

Inputs are subscribed for the life of the BMA (not only while active), so a direction set while
the swarm is still on the ground, and the latest heading, are known from the first tick.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Literal

from pydantic import Field

from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.msgs import (
    direction_cmd_t,
    payload_t,
    peer_detection_t,
    telemetry_t,
    velocity_cmd_t,
)
from behaviors.dovrat_swarm.logic import (
    Detection,
    DetectionTracker,
    OperatorDirection,
    SwarmCommand,
    SwarmParams,
    finite_direction,
    parse_detection_payload,
    swarm_command,
)
from behaviors.velocity import velocity_cmd


class DovratSwarm(Behavior):
    """Fly forward, turn gently while a peer is ahead and sharply while none is, drift with the operator."""

    class Params(SwarmParams):
        #: A detection older than this (s) counts as "no peer".
        detection_timeout: float = Field(default=2.0, gt=0, allow_inf_nan=False)
        #: Heading older than this (s) is unknown: the operator's drift is left out meanwhile.
        telemetry_timeout: float = Field(default=1.0, gt=0, allow_inf_nan=False)
        #: Where detections come from: a sensor's PEER_DETECTION, the station's OPERATOR_PAYLOAD, or both.
        detection_source: Literal["any", "peer_detection", "payload"] = "any"

    params: Params
    topics = {
        "TELEMETRY": telemetry_t,
        "DIRECTION_CMD": direction_cmd_t,
        "SWARM_DIRECTION_CMD": direction_cmd_t,
        "PEER_DETECTION": peer_detection_t,
        "OPERATOR_PAYLOAD": payload_t,
        "VELOCITY_CMD": velocity_cmd_t,
    }
    activate_on = ("MISSION",)
    tick_hz = 10.0

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        p = self.params
        self.detections = DetectionTracker(p.detection_timeout)
        self.direction: OperatorDirection | None = None
        self._heading: float | None = None
        self._heading_at = 0.0
        self.last_command: SwarmCommand | None = None
        self._reject_log = RateLimitedLog(self.log, period=10.0)
        ctx.subscribe("TELEMETRY", self._on_telemetry)
        ctx.subscribe("DIRECTION_CMD", self._on_direction)
        ctx.subscribe("SWARM_DIRECTION_CMD", self._on_direction)
        if p.detection_source in ("any", "peer_detection"):
            ctx.subscribe("PEER_DETECTION", self._on_peer_detection)
        if p.detection_source in ("any", "payload"):
            ctx.subscribe("OPERATOR_PAYLOAD", self._on_payload)

    # ------------------------------------------------------------------ inputs
    def _on_telemetry(self, msg: telemetry_t) -> None:
        heading = float(msg.heading)
        if not math.isfinite(heading):  # unknown (an adapter without a compass), not an error
            return
        self._heading = heading
        self._heading_at = self.ctx.now

    def _on_direction(self, msg: direction_cmd_t) -> None:
        if msg.target not in ("", self.ctx.agent):
            return
        # Authenticated and range-checked by the node already (docs/security.md); this guard keeps
        # the rule safe if the behavior is ever fed by something else.
        direction = OperatorDirection(bool(msg.active), float(msg.azimuth), float(msg.speed))
        if not finite_direction(direction):
            self._reject_log.log(
                "direction",
                logging.WARNING,
                "ignored a direction from %r: azimuth %r, speed %r",
                msg.header.agent,
                msg.azimuth,
                msg.speed,
            )
            return
        self.direction = direction
        self.log.info(
            "operator direction: %s",
            f"{msg.azimuth:.0f} deg at {msg.speed:g} m/s" if msg.active else "none",
        )

    def _on_peer_detection(self, msg: peer_detection_t) -> None:
        detection = Detection(
            bool(msg.detected), max(0, int(msg.count)), float(msg.nearest_range), float(msg.nearest_bearing)
        )
        self.detections.update(detection, self.ctx.now)

    def _on_payload(self, msg: payload_t) -> None:
        detection = parse_detection_payload(bytes(msg.data))
        if detection is None:
            self._reject_log.log(
                "payload",
                logging.DEBUG,
                "operator payload (%s) holds no detection; ignored",
                msg.content_type,
            )
            return
        self.detections.update(detection, self.ctx.now)

    # ------------------------------------------------------------------ control
    def heading(self, now: float | None = None) -> float | None:
        """The last heard heading, None once it is older than ``telemetry_timeout`` at ``now``
        (default: the context's now)."""
        if now is None:
            now = self.ctx.now
        if self._heading is None or now - self._heading_at > self.params.telemetry_timeout:
            return None
        return self._heading

    def on_activate(self) -> None:
        self.log.info(
            "swarming: %g m/s, turning %s",
            self.params.forward_speed,
            "clockwise" if self.params.turn_direction > 0 else "counter-clockwise",
        )

    def tick(self, dt: float) -> None:
        now = self.ctx.now
        command = swarm_command(self.heading(now), self.detections.detected(now), self.direction, self.params)
        self.last_command = command
        self._publish(command.vx, command.vy, command.yaw_rate)

    def on_deactivate(self) -> None:
        self.last_command = None
        self._publish(0.0, 0.0, 0.0)

    def _publish(self, vx: float, vy: float, yaw_rate: float) -> None:
        self.ctx.publish("VELOCITY_CMD", velocity_cmd(vx, vy, frame=velocity_cmd_t.BODY, yaw_rate=yaw_rate))

    def status(self) -> dict[str, Any]:
        """A snapshot for tests and debugging."""
        return {
            "heading": self.heading(),
            "detected": self.detections.detected(self.ctx.now),
            "direction": self.direction,
            "command": self.last_command,
        }
