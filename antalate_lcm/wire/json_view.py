"""Which channels, schemas and JSON messages an LCM message becomes, for an MCAP file and for the live
Foxglove server alike (``mcap_log`` and ``foxglove_server`` write what this returns).

Each antalate message goes out on a channel named as on the bus (``uav-1/TELEMETRY``) in JSON with
the schema of its type (``lcm_json``); a telemetry_t also feeds ``{agent}/location``
(``foxglove.LocationFix``: the Map panel) and ``swarm/scene`` (``foxglove.SceneUpdate``: the 3D
panel), an hlc_error_t ``swarm/log`` (``foxglove.Log``). With ``raw`` the LCM bytes are kept too, on
``raw/{channel}`` (message encoding ``lcm``, the ``.lcm`` text as schema), exactly as received, MAC
included. Every channel made from a bus message names its LCM channel and type in its metadata, so
a reader turns the file back into LCM events (``read_events``). Pure: the clock comes in as arguments.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.msgs import hlc_error_t, mc_state_t, telemetry_t
from antalate_lcm.wire import foxglove_msgs, lcm_json
from antalate_lcm.wire.topics import TOPICS, route
from antalate_lcm.wire.vocabulary import McState, name_of

RAW_PREFIX = "raw/"
RAW_ENCODING = "lcm"
#: Channel metadata keys: the LCM channel and type a channel's messages came from.
META_CHANNEL = "lcm_channel"
META_TYPE = "lcm_type"
LOCATION_TOPIC = "{agent}/location"
SCENE_TOPIC = "swarm/scene"
LOG_TOPIC = "swarm/log"
#: Every LCM instance multicasts one when it starts: the library's, not the swarm's.
SELF_TEST = "LCM_SELF_TEST"


@dataclass(frozen=True)
class ChannelSpec:
    """What a channel is announced with (MCAP Schema + Channel records, a Foxglove advertisement)."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    metadata: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class Output:
    channel: ChannelSpec
    data: bytes
    publish_ns: int


def dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


def _json_spec(
    topic: str, name: str, schema: dict[str, Any], meta: tuple[tuple[str, str], ...]
) -> ChannelSpec:
    return ChannelSpec(topic, name, lcm_json.SCHEMA_ENCODING, dumps(schema), lcm_json.MESSAGE_ENCODING, meta)


@dataclass
class JsonView:
    """Turns LCM events into channel messages; remembers what a well-known message needs from earlier
    ones (the 3D frame's origin, each agent's MC state) and counts what it could not turn."""

    raw: bool = False
    #: LCM channels that are not antalate's (kept only with ``raw``), by name: how many messages.
    unknown: dict[str, int] = field(default_factory=dict)
    #: antalate channels whose bytes did not decode as their type (kept only with ``raw``).
    undecodable: dict[str, int] = field(default_factory=dict)
    _specs: dict[tuple[str, str], ChannelSpec] = field(default_factory=dict)
    _frame: FlatFrame | None = None
    _mc: dict[str, int] = field(default_factory=dict)

    def _spec(self, kind: str, topic: str, type_name: str, channel: str) -> ChannelSpec:
        key = (kind, topic)
        spec = self._specs.get(key)
        if spec is None:
            meta = ((META_CHANNEL, channel), (META_TYPE, type_name))
            if kind == "raw":
                known = type_name in lcm_json.structs()
                spec = ChannelSpec(
                    topic,
                    lcm_json.schema_name(type_name) if known else "",
                    RAW_ENCODING if known else "",
                    lcm_json.lcm_text(type_name).encode() if known else b"",
                    RAW_ENCODING,
                    meta,
                )
            elif kind == "json":
                spec = _json_spec(topic, lcm_json.schema_name(type_name), lcm_json.schema(type_name), meta)
            else:
                spec = _json_spec(topic, kind, foxglove_msgs.SCHEMAS[kind], ())
            self._specs[key] = spec
        return spec

    def translate(self, channel: str, log_ns: int, data: bytes) -> list[Output]:
        """The channel messages of one LCM event heard (or logged) at ``log_ns`` ns since the epoch."""
        routed = route(channel)
        if routed is None:
            if channel != SELF_TEST:
                self.unknown[channel] = self.unknown.get(channel, 0) + 1
            if not self.raw:
                return []
            return [Output(self._spec("raw", RAW_PREFIX + channel, "", channel), data, log_ns)]
        topic, agent = routed
        msg_type = TOPICS[topic].msg_type
        type_name = msg_type.__name__
        out: list[Output] = []
        if self.raw:
            out.append(Output(self._spec("raw", RAW_PREFIX + channel, type_name, channel), data, log_ns))
        try:
            msg: Any = msg_type.decode(data)
        except Exception:  # noqa: BLE001 - whatever a sender put on the bus is counted, never fatal
            self.undecodable[channel] = self.undecodable.get(channel, 0) + 1
            return out
        utime = int(msg.header.utime)
        publish_ns = utime * 1000 if 0 < utime < (1 << 63) // 1000 else log_ns
        out.append(
            Output(self._spec("json", channel, type_name, channel), dumps(lcm_json.to_json(msg)), publish_ns)
        )
        out.extend(self._well_known(agent or str(msg.header.agent), log_ns, msg))
        return out

    def _well_known(self, agent: str, ns: int, msg: Any) -> list[Output]:
        if isinstance(msg, mc_state_t):
            self._mc[agent] = int(msg.state)
            return []
        if isinstance(msg, hlc_error_t):
            entry = foxglove_msgs.log_entry(agent, ns, int(msg.severity), str(msg.text), int(msg.code))
            return [Output(self._spec(foxglove_msgs.LOG, LOG_TOPIC, "", ""), dumps(entry), ns)]
        if not isinstance(msg, telemetry_t):
            return []
        lat, lon, alt = float(msg.lat), float(msg.lon), float(msg.alt)
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
            return []  # a broken fix has no place on a map; its telemetry_t is still on its channel
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return []
        if self._frame is None:
            self._frame = FlatFrame(lat, lon)
        north, east = self._frame.to_ne(lat, lon)
        mc = self._mc.get(agent)
        battery = float(msg.battery)
        label = f"{agent} {name_of(McState, mc) or '?' if mc is not None else '?'}"
        if math.isfinite(battery) and battery >= 0:
            label += f" {battery:.0f}%"
        fix = foxglove_msgs.location_fix(agent, ns, lat, lon, alt)
        scene = foxglove_msgs.scene_update(agent, ns, (east, north, alt), float(msg.heading), label, mc)
        location_topic = LOCATION_TOPIC.format(agent=agent)
        return [
            Output(self._spec(foxglove_msgs.LOCATION_FIX, location_topic, "", ""), dumps(fix), ns),
            Output(self._spec(foxglove_msgs.SCENE_UPDATE, SCENE_TOPIC, "", ""), dumps(scene), ns),
        ]
