"""Reading LCM log files (``lcm-logger``, ``antalate log``) and antalate's MCAP files
(``antalate log -o X.mcap``, ``antalate export``) into a :class:`SwarmRecord`.

This is the only module of the analysis that touches files (an MCAP file is read as the LCM events
it holds, by ``antalate_lcm.core.mcap_log``, so both kinds go through one decoding). Messages are recognised by their
channel (the default channel templates of :data:`antalate_lcm.wire.topics.TOPICS`, e.g.
``uav-1/TELEMETRY``) and decoded with their LCM type. A log is what a logger happened to hear, so
nothing in it is trusted: an event that does not decode, or a channel that is not antalate's, is
counted and skipped, never fatal. Only a file that is not an LCM log at all is an error.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

from antalate_lcm.apps.analysis.records import (
    DirectionCommand,
    FaultRecord,
    SafetyEvent,
    SwarmRecord,
    TelemetrySample,
)
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.lcm_log import log_events, open_log
from antalate_lcm.core.mcap_log import McapEvents, is_mcap, read_events
from antalate_lcm.msgs import direction_cmd_t, hlc_error_t, hlc_state_t, mc_state_t, payload_t, telemetry_t
from antalate_lcm.transports import captured_stderr
from antalate_lcm.wire.topics import FAULT_CHANNEL, FAULT_CONTENT_TYPE, TOPICS, route
from antalate_lcm.wire.vocabulary import HlcState, McState, name_of

#: Every LCM log event starts with this sync word (big-endian), so a file that does not is no log.
LOG_SYNC_WORD = 0xEDA1DA01

#: Topics the analysis decodes.
_USED = ("SWARM_DIRECTION_CMD", "MC_STATE", "HLC_STATE", "TELEMETRY", "DIRECTION_CMD", "HLC_ERROR")
#: ``hlc_error_t.code`` of the safety filter's reports (antalate_lcm.agent.hlc.machine.ErrorCode.SAFETY).
SAFETY_CODE = 14


def check_log_file(path: str | Path) -> Path:
    """The path, if it names a readable LCM log; else an :class:`AntalateError` saying what is wrong.

    liblcm would silently read zero events from any file that is not a log, which would surface
    later as a confusing "no agents"; checking the first sync word turns that into a clear message.
    """
    p = Path(path)
    try:
        with p.open("rb") as f:
            head = f.read(4)
    except FileNotFoundError:
        raise AntalateError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise AntalateError(f"{p}: is a directory, not an LCM log file") from None
    except OSError as exc:
        raise AntalateError(f"{p}: cannot be read: {exc.strerror or exc}") from None
    if not head:
        raise AntalateError(f"{p}: empty file, not an LCM log (did the logger hear anything?)")
    if len(head) < 4 or struct.unpack(">I", head)[0] != LOG_SYNC_WORD:
        raise AntalateError(f"{p}: not an LCM log file (it does not start with an LCM event header)")
    return p


def read_log(path: str | Path) -> SwarmRecord:
    """Decode every antalate state, telemetry and direction message of an LCM log or an MCAP file.

    Raises :class:`AntalateError` for a missing, unreadable or non-log file. A log that ends in
    garbage (a logger killed mid-write, a damaged copy) yields what precedes the damage, with
    :attr:`SwarmRecord.truncated` saying where reading stopped.
    """
    if is_mcap(path):
        return _read_mcap(Path(path))
    p = check_log_file(path)
    record = SwarmRecord(path=str(p))
    reader = _Reader(record)
    log = open_log(p)
    # liblcm prints "Invalid header after log data" on fd 2 when it meets damage; we report it ourselves.
    with captured_stderr():
        try:
            size = log.size()
            for t, channel, data in log_events(log):
                reader.add(t, channel, data)
            position = log.tell()
        finally:
            log.close()
    if position < size:
        record.truncated = (
            f"reading stopped at byte {position} of {size}: the rest is not valid LCM events "
            "(a truncated or damaged log)"
        )
    return record


def _read_mcap(p: Path) -> SwarmRecord:
    """An MCAP file antalate wrote (``antalate log -o X.mcap``, ``antalate export``): its bus
    messages are read back as the LCM events they were, then decoded as any log's."""
    record = SwarmRecord(path=str(p))
    reader = _Reader(record)
    report = McapEvents()
    try:
        for utime, channel, data in read_events(p, report):
            reader.add(utime, channel, data)
    except OSError as exc:
        raise AntalateError(f"{p}: cannot be read: {exc.strerror or exc}") from None
    for channel, n in report.skipped_json.items():
        record.undecodable[channel] = record.undecodable.get(channel, 0) + n
    record.truncated = report.truncated
    return record


class _Reader:
    """One log's events into a record, whatever file they came from."""

    def __init__(self, record: SwarmRecord) -> None:
        self.record = record
        self.routes: dict[str, tuple[str, str] | None] = {}
        self.last_direction: dict[str, tuple[bool, float, float, str]] = {}

    def add(self, utime: int, channel: str, data: bytes) -> None:
        record = self.record
        if record.events == 0:
            record.start_utime = utime
        record.events += 1
        t = (utime - record.start_utime) / 1e6
        record.duration = max(record.duration, t)
        if channel not in self.routes:
            self.routes[channel] = route(channel)
        routed = self.routes[channel]
        if channel == FAULT_CHANNEL:
            _fault_into(record, channel, t, data)
            return
        if routed is None and channel == "LCM_SELF_TEST":
            # Every LCM instance multicasts one when it starts: the library's, not garbage.
            record.unused[channel] = record.unused.get(channel, 0) + 1
            return
        if routed is None:
            record.unknown[channel] = record.unknown.get(channel, 0) + 1
            return
        _decode_into(record, routed, channel, t, data, self.last_direction)


def _fault_into(record: SwarmRecord, channel: str, t: float, data: bytes) -> None:
    """One fault record (an experiment's), or counted undecodable."""
    try:
        msg = payload_t.decode(data)
        if msg.content_type != FAULT_CONTENT_TYPE:
            raise ValueError(msg.content_type)
        fields = json.loads(bytes(msg.data))
        agent, kind, event = str(fields.pop("agent")), str(fields.pop("kind")), str(fields.pop("event"))
    except Exception:  # noqa: BLE001 - any garbage is counted, never fatal
        record.undecodable[channel] = record.undecodable.get(channel, 0) + 1
        return
    record.faults.append(FaultRecord(t, agent, kind, event, fields))


def _decode_into(
    record: SwarmRecord,
    route: tuple[str, str],
    channel: str,
    t: float,
    data: bytes,
    last_direction: dict[str, tuple[bool, float, float, str]],
) -> None:
    topic, agent = route
    msg_type = TOPICS[topic].msg_type
    if topic not in _USED:
        record.unused[topic] = record.unused.get(topic, 0) + 1
        return
    try:
        msg: Any = msg_type.decode(data)
    except Exception:  # noqa: BLE001 - any garbage is counted, never fatal
        record.undecodable[channel] = record.undecodable.get(channel, 0) + 1
        return
    if isinstance(msg, direction_cmd_t):
        # On an agent's own channel only that agent hears it, whatever its (possibly empty) target says.
        target = "" if topic == "SWARM_DIRECTION_CMD" else (msg.target or agent)
        key = (bool(msg.active), float(msg.azimuth), float(msg.speed), target)
        # A console repeats its direction every second (it is a state, like a stick): keep changes only.
        if last_direction.get(channel) != key:
            last_direction[channel] = key
            record.directions.append(
                DirectionCommand(t, key[0], key[1], key[2], target, str(msg.header.agent))
            )
        return
    rec = record.agent(agent or str(msg.header.agent))
    rec.last_heard = t
    if isinstance(msg, telemetry_t):
        rec.telemetry.append(
            TelemetrySample(
                t,
                float(msg.lat),
                float(msg.lon),
                float(msg.alt),
                float(msg.heading),
                bool(msg.in_air),
                float(msg.battery),
                float(msg.vn),
                float(msg.ve),
            )
        )
    elif isinstance(msg, mc_state_t):
        rec.add_state(rec.mc_states, t, name_of(McState, msg.state) or f"?{msg.state}")
    elif isinstance(msg, hlc_state_t):
        rec.add_state(rec.hlc_states, t, name_of(HlcState, msg.state) or f"?{msg.state}")
    elif isinstance(msg, hlc_error_t) and msg.code == SAFETY_CODE:
        record.safety_events.append(SafetyEvent(t, rec.name, int(msg.severity), str(msg.text)))
