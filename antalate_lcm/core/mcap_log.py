"""MCAP files of a flight: written from LCM events (``json_view`` says what each becomes), read back
as LCM events (what ``analysis.logfile`` analyses).

MCAP is the file Foxglove, PlotJuggler, ``rosbags`` and the ``mcap`` tools share; antalate writes it
with the ``mcap`` library (the ``mcap`` extra), zstd-compressed chunks, with the summary and indexes
a viewer seeks by. Reading streams the records instead of seeking, so a file whose writer was killed
(no summary) still yields every complete message before the damage, as with an LCM log.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.wire import lcm_json
from antalate_lcm.wire.json_view import META_CHANNEL, META_TYPE, RAW_ENCODING, ChannelSpec, JsonView

MCAP_MISSING = "MCAP files need the mcap library, which is not installed: pip install 'antalate[mcap]'"
#: The 8 bytes every MCAP file starts with (the spec's magic: 0x89, "MCAP", the version "0", CR, LF).
MCAP_MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "antalate"


def is_mcap(path: str | Path) -> bool:
    """Whether ``path`` starts as an MCAP file (by its magic, whatever its name)."""
    try:
        with Path(path).open("rb") as f:
            return f.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError:
        return False


class McapLogWriter:
    """An MCAP file being written from LCM events. Not thread-safe: one thread writes (the executor's
    when recording a bus)."""

    def __init__(self, out: IO[bytes], *, raw: bool = False) -> None:
        try:
            from mcap.writer import Writer
        except ImportError:
            raise AntalateError(MCAP_MISSING) from None
        self.view = JsonView(raw=raw)
        self.messages = 0
        self.events = 0
        self._writer = Writer(out)
        self._writer.start(profile="", library=LIBRARY)
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[ChannelSpec, int] = {}
        self._sequence: dict[int, int] = {}

    def _channel_id(self, spec: ChannelSpec) -> int:
        cid = self._channels.get(spec)
        if cid is None:
            schema_id = 0  # MCAP: a channel with no schema (a non-antalate channel kept raw)
            if spec.schema_name or spec.schema_data:
                key = (spec.schema_name, spec.schema_encoding, spec.schema_data)
                schema_id = self._schemas.get(key, 0)
                if not schema_id:
                    schema_id = self._schemas[key] = self._writer.register_schema(*key)
            cid = self._channels[spec] = self._writer.register_channel(
                spec.topic, spec.message_encoding, schema_id, dict(spec.metadata)
            )
        return cid

    def write_event(self, channel: str, log_ns: int, data: bytes) -> None:
        self.events += 1
        for out in self.view.translate(channel, log_ns, data):
            cid = self._channel_id(out.channel)
            seq = self._sequence.get(cid, 0)
            self._sequence[cid] = (seq + 1) & 0xFFFFFFFF
            self._writer.add_message(cid, log_ns, out.data, out.publish_ns, seq)
            self.messages += 1

    def finish(self) -> None:
        """Write the summary and indexes (a viewer needs them to seek)."""
        self._writer.finish()  # type: ignore[no-untyped-call]


@dataclass
class McapEvents:
    """What :func:`read_events` met besides the events: why it stopped early, if it did."""

    truncated: str = ""
    skipped_json: dict[str, int] = field(default_factory=dict)


def read_events(path: Path, report: McapEvents) -> Iterator[tuple[int, str, bytes]]:
    """``(utime, channel, LCM bytes)`` of every bus message an MCAP file holds, in file order.

    A channel kept raw gives its bytes as received; a JSON one, when the file has no raw twin of it,
    is encoded back from its fields (``lcm_json.from_json``: the same bytes for every message antalate
    wrote). Channels antalate did not make from a bus message (the Foxglove ones) are not events. A
    JSON message that is no longer a message of its type is counted in ``report``, not fatal.
    """
    try:
        from mcap.exceptions import McapError
        from mcap.records import Channel, Message
        from mcap.stream_reader import StreamReader
    except ImportError:
        raise AntalateError(MCAP_MISSING) from None
    # First pass on the channels only: a raw channel must win over its JSON twin wherever it appears.
    channels: dict[int, Channel] = {}
    raw_of: set[str] = set()
    messages: list[tuple[int, Message]] = []
    with path.open("rb") as f:
        reader = StreamReader(f, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                    if record.message_encoding == RAW_ENCODING and META_CHANNEL in record.metadata:
                        raw_of.add(record.metadata[META_CHANNEL])
                elif isinstance(record, Message):
                    messages.append((record.channel_id, record))
        except (McapError, EOFError, struct.error, ValueError, KeyError) as exc:
            report.truncated = (
                f"reading stopped after {len(messages)} messages: the rest is not valid MCAP ({exc})"
            )
    for channel_id, message in messages:
        channel = channels.get(channel_id)
        if channel is None or META_CHANNEL not in channel.metadata:
            continue
        lcm_channel = channel.metadata[META_CHANNEL]
        utime = message.log_time // 1000
        if channel.message_encoding == RAW_ENCODING:
            yield utime, lcm_channel, message.data
        elif channel.message_encoding == lcm_json.MESSAGE_ENCODING and lcm_channel not in raw_of:
            data = _json_to_lcm(channel.metadata.get(META_TYPE, ""), message.data)
            if data is None:
                report.skipped_json[lcm_channel] = report.skipped_json.get(lcm_channel, 0) + 1
            else:
                yield utime, lcm_channel, data


def _json_to_lcm(type_name: str, data: bytes) -> bytes | None:
    try:
        obj: Any = json.loads(data)
        encoded: bytes = lcm_json.from_json(type_name, obj).encode()
    except Exception:  # noqa: BLE001 - a hand-edited or foreign file: counted by the caller
        return None
    return encoded


def export(lcm_path: Path, out_path: Path, *, raw: bool = False) -> McapLogWriter:
    """Convert an LCM log (``lcm-logger``, ``antalate log``) to MCAP; a damaged tail ends it early,
    as it ends :func:`antalate_lcm.apps.analysis.read_log`."""
    from antalate_lcm.core.lcm_log import log_events, open_log
    from antalate_lcm.transports import captured_stderr

    log = open_log(lcm_path)
    try:
        out = out_path.open("wb")
    except OSError as exc:
        log.close()
        raise AntalateError(f"cannot write {out_path}: {exc.strerror or exc}") from None
    with out, captured_stderr():
        writer = McapLogWriter(out, raw=raw)
        try:
            for t, channel, data in log_events(log):
                writer.write_event(channel, t * 1000, data)
        finally:
            log.close()
            writer.finish()
    return writer
