"""The topic table: every topic name a config can bind, its message type and default channel.

Topics are the names nodes and behaviors use (``"MC_STATE"``); channels are what travels on the wire
(``"alpha/MC_STATE"``). Keeping the table here means a config can remap any channel without code changes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Protocol

from antalate_lcm.msgs import (
    arbiter_status_t,
    behavior_state_t,
    direction_cmd_t,
    header_t,
    hlc_error_t,
    hlc_state_t,
    mc_state_t,
    operator_cmd_t,
    payload_t,
    peer_detection_t,
    peer_scan_t,
    telemetry_t,
    velocity_cmd_t,
)


class Message(Protocol):
    """What the bus, the log readers and the console rely on in every message class (the surface
    typed in ``msgs/*.pyi``), so a table of mixed types still checks ``decode`` and ``header``."""

    header: header_t

    def encode(self) -> bytes: ...

    @staticmethod
    def decode(data: bytes) -> Message: ...


#: Every LCM type antalate defines, by type name (used by log readers and ``antalate spy``).
MESSAGE_TYPES: dict[str, type[Message]] = {
    t.__name__: t
    for t in (
        mc_state_t,
        hlc_state_t,
        telemetry_t,
        hlc_error_t,
        velocity_cmd_t,
        operator_cmd_t,
        direction_cmd_t,
        payload_t,
        behavior_state_t,
        arbiter_status_t,
        peer_detection_t,
        peer_scan_t,
    )
}


@dataclass(frozen=True)
class TopicSpec:
    """A topic's message type and its default channel template (``{agent}``, ``{arbiter}``, ... fields)."""

    msg_type: type[Message]
    channel: str


TOPICS: dict[str, TopicSpec] = {
    "MC_STATE": TopicSpec(mc_state_t, "{agent}/MC_STATE"),
    "HLC_STATE": TopicSpec(hlc_state_t, "{agent}/HLC_STATE"),
    "TELEMETRY": TopicSpec(telemetry_t, "{agent}/TELEMETRY"),
    "HLC_ERROR": TopicSpec(hlc_error_t, "{agent}/HLC_ERROR"),
    "VELOCITY_CMD": TopicSpec(velocity_cmd_t, "{agent}/VELOCITY_CMD"),
    "OPERATOR_CMD": TopicSpec(operator_cmd_t, "{agent}/OPERATOR_CMD"),
    "DIRECTION_CMD": TopicSpec(direction_cmd_t, "{agent}/DIRECTION_CMD"),
    "OPERATOR_PAYLOAD": TopicSpec(payload_t, "{agent}/OPERATOR_PAYLOAD"),
    "OPERATOR_FEEDBACK": TopicSpec(payload_t, "{agent}/OPERATOR_FEEDBACK"),
    "ARBITER": TopicSpec(arbiter_status_t, "{agent}/ARBITER/{arbiter}"),
    "PEER_DETECTION": TopicSpec(peer_detection_t, "{agent}/PEER_DETECTION"),
    "PEER_SCAN": TopicSpec(peer_scan_t, "{agent}/PEER_SCAN"),
    "SWARM_OPERATOR_CMD": TopicSpec(operator_cmd_t, "SWARM/OPERATOR_CMD"),
    "SWARM_DIRECTION_CMD": TopicSpec(direction_cmd_t, "SWARM/DIRECTION_CMD"),
}

#: Topics whose messages come from outside the agent (an operator, the station via the OSC, a tool):
#: any sender may publish them, so they are authenticated by the swarm key alone.
OPERATOR_INPUTS = frozenset(
    {"OPERATOR_CMD", "DIRECTION_CMD", "OPERATOR_PAYLOAD", "SWARM_OPERATOR_CMD", "SWARM_DIRECTION_CMD"}
)

#: Where an experiment records the faults it injects (``payload_t`` of :data:`FAULT_CONTENT_TYPE`,
#: one JSON object each: antalate_lcm.runtime.faults), read back by ``antalate analyze``.
FAULT_CHANNEL = "ANTALATE/FAULT"
FAULT_CONTENT_TYPE = "application/vnd.antalate.fault+json"

#: Message types whose replay memory (per-sender high-water utime) survives a restart: the ones an
#: operator sends. State and velocity messages are superseded within a period anyway.
PERSISTED_TYPES = frozenset({"operator_cmd_t", "direction_cmd_t", "payload_t"})


def is_internal(topic: str) -> bool:
    """Whether ``topic`` is published by the agent's own nodes (MC_STATE, HLC_STATE, TELEMETRY,
    VELOCITY_CMD, a cascaded behavior state, ...): its sender must be the agent its channel names,
    and between nodes of one process it travels in memory."""
    return topic not in OPERATOR_INPUTS


_FIELD = re.compile(r"\{(\w+)\}")


def channel_regex(template: str, **known: str) -> str:
    """An LCM-style regex matching every channel the template can produce.

    Fields given in ``known`` are filled in literally; the others match one path segment and are
    captured as named groups, so a watcher (the TUI) can recover the agent name from the channel.
    """
    out: list[str] = []
    pos = 0
    seen: set[str] = set()
    for m in _FIELD.finditer(template):
        out.append(re.escape(template[pos : m.start()]))
        name = m.group(1)
        if name in known:
            out.append(re.escape(known[name]))
        elif name in seen:
            out.append(f"(?P={name})")
        else:
            out.append(f"(?P<{name}>[^/]+)")
            seen.add(name)
        pos = m.end()
    out.append(re.escape(template[pos:]))
    return "".join(out)


#: Topics by default channel, fixed channels first: ``SWARM/DIRECTION_CMD`` would also match
#: ``{agent}/DIRECTION_CMD`` with an agent called "SWARM".
_ROUTES: list[tuple[str, re.Pattern[str]]] = [
    (topic, re.compile(channel_regex(spec.channel)))
    for topic, spec in sorted(TOPICS.items(), key=lambda item: "{" in item[1].channel)
]


def route(channel: str) -> tuple[str, str] | None:
    """``(topic, agent)`` of a channel named by the default templates (``uav-1/TELEMETRY`` ->
    ``("TELEMETRY", "uav-1")``; ``""`` for a swarm channel), None for any other channel: what lets a
    log reader or a converter that has no config tell each message's type from its channel."""
    for topic, pattern in _ROUTES:
        m = pattern.fullmatch(channel)
        if m is not None:
            return topic, m.groupdict().get("agent", "")
    return None
