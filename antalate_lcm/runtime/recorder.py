"""Record every channel of one bus to an LCM log from inside a process (``antalate run -o``).

The file is what ``lcm-logger`` writes (``lcm.EventLog``), byte for byte, so ``antalate analyze``,
``lcm-logplayer`` and the ``file://`` provider read it. Recording inside the process, rather than
starting ``lcm-logger`` beside it, also works on ``memq://`` (one process, no multicast route
needed) and misses nothing at the start: the subscription exists before the first agent node starts.

The events are written here rather than through ``lcm.EventLog.write_event``: liblcm's
``lcm_eventlog_write_event`` (lcm/eventlog.c) writes each event as a 28-byte big-endian head (the
magic ``0xEDA1DA01``, the event number counted from 0, the timestamp, the channel's and the data's
lengths), the channel's bytes and the data, one ``fwrite`` per field. A thousand simulated agents
record 40,000 events a second; one ``struct.pack`` into a buffer and the channel's bytes costs
8-20 % less than that call (docs/simulator.md, issue 32's fifth pass);
tests/experiments/test_recorder.py reads the file back with ``lcm.EventLog`` and compares it with
what ``write_event`` writes.

What a process killed without stopping may lose is bounded the way ``lcm-logger`` bounds it: by
time. lcm-logger flushes its file (``fflush``, then ``fdatasync``) after writing an event stamped
more than ``--flush-interval`` (100 ms by default) after its last flush (lcm-logger/lcm_logger.c,
``needs_flushed``; ``fflush_interval_ms = 100`` in ``main``); between two, its stdio buffer and its
write queue (up to ``--max-unwritten-mb``, 100 MB) hold what it received. Here the buffer goes to
the kernel on the same rule, on the events' own stamps, and at 64 KiB at the latest: a killed
process's log holds every event stamped more than 100 ms before its last one. At 4 KiB (the stdio
buffer's size) a thousand simulated agents' 40,000 events a second were 1,500 writes a second.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import BinaryIO

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.bus import Subscription
from antalate_lcm.core.node import Context, Node, NodeSettings

#: An event's head in liblcm's log (lcm/eventlog.c): magic, event number, utime, channel and data lengths.
_EVENT = struct.Struct(">IqqII")
_MAGIC = 0xEDA1DA01
#: µs of events held back at most: lcm-logger's default ``--flush-interval`` (module docstring).
FLUSH_INTERVAL_US = 100_000
#: Bytes buffered at most before they are written; a buffer that stays in the core's cache (4 KiB:
#: 1.4x the CPU per event, 256 KiB: 1.3x; docs/simulator.md, issue 32's sixth pass).
FLUSH_AT = 1 << 16


def _write_all(write: Callable[[bytearray | memoryview], int | None], data: bytearray) -> None:
    """``data`` through an unbuffered file's ``write``, which may take less than all of it."""
    view = memoryview(data)
    while view:
        n = write(view)
        if not n:  # a blocking file takes at least a byte or raises: never spin
            raise OSError("the log file took none of the bytes written to it")
        view = view[n:]


class LogRecorder(Node):
    """A node that writes every message heard on ``bus`` (its channel, bytes and arrival time on the
    nodes' wall clock: simulated with ``antalate run --speed``)."""

    kind = "recorder"

    def __init__(self, settings: NodeSettings, context: Context, *, bus: str, path: str) -> None:
        super().__init__(settings, context, name="recorder")
        self.bus = bus
        self.path = path
        self._file: BinaryIO | None = None
        self._buffer = bytearray()
        self._count: Callable[[], int] = lambda: 0
        self._sub: Subscription | None = None

    @property
    def events(self) -> int:
        """Events recorded so far."""
        return self._count()

    def on_start(self) -> None:
        try:
            # Unbuffered: _buffer is the one buffer (a second one would hold more back from the disk).
            self._file = open(self.path, "wb", buffering=0)  # noqa: SIM115 - closed in on_stop
        except OSError as exc:
            raise AntalateError(f"cannot write the log {self.path}: {exc}") from None
        self._sub = self.context.buses.subscribe(self.bus, ".*", None, self._writer(self._file), regex=True)

    def _writer(self, file: BinaryIO) -> Callable[[str, bytes], None]:
        """The subscription's handler: everything it touches per event bound here, once."""
        buffer = self._buffer
        head = _EVENT.pack
        write = file.write
        n = 0
        due = -1  # the first event is written at once (and the file's head with it)

        def record(channel: str, data: bytes) -> None:  # on the executor's loop thread
            nonlocal n, due
            # Encoded each time: a table of 8,000 channels' bytes (1,000 agents) was a cache miss
            # or two per event, a third more than the copy (docs/simulator.md, sixth pass).
            name = channel.encode()
            buf = buffer  # (a local name: += on the closure's own would make it local)
            utime = int(self.wallclock() * 1e6)
            buf += head(_MAGIC, n, utime, len(name), len(data))
            buf += name
            buf += data
            n += 1
            if utime > due or len(buf) >= FLUSH_AT:
                _write_all(write, buf)
                buf.clear()
                due = utime + FLUSH_INTERVAL_US

        self._count = lambda: n
        return record

    def on_stop(self) -> None:
        if self._sub is not None:
            self.context.buses.unsubscribe(self._sub)
            self._sub = None
        file, self._file = self._file, None
        if file is not None:
            _write_all(file.write, self._buffer)
            self._buffer.clear()
            file.close()
