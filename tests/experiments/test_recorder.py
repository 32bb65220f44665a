"""The in-process recorder writes what liblcm's ``lcm.EventLog.write_event`` writes, byte for byte."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import lcm
import pytest

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Context, NodeSettings
from antalate_lcm.runtime.recorder import LogRecorder


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context.in_process({"lan": "memq://"})
    ctx.executor.start()
    yield ctx
    ctx.close()


def _recorder(context: Context, path: Path) -> LogRecorder:
    settings = NodeSettings.from_config(
        parse_config({"agent": {"name": "recorder"}, "buses": {"lan": "memq://"}})
    )
    return LogRecorder(settings, context, bus="lan", path=str(path))


def test_the_log_is_byte_for_byte_what_lcm_eventlog_writes(context: Context, tmp_path: Path) -> None:
    """Events of every size (none, a datagram's, past the recorder's buffer), channels of any
    characters, in order, with their event numbers and times: lcm.EventLog reads them back, and
    writing what it read with lcm.EventLog gives the same file."""
    path = tmp_path / "run.lcmlog"
    recorder = _recorder(context, path)
    times = iter(range(1_700_000_000_000_000, 1_800_000_000_000_000, 1_234))
    recorder.wallclock = lambda: next(times) / 1e6
    sent = [(f"b-{i % 5:03d}/MC_STATE", bytes([i % 256]) * (i * 37 % 1500)) for i in range(300)]
    sent += [("empty", b""), ("Zürich ✈/TELEMETRY", b"\x00\xff"), ("big", b"x" * 200_000), ("after", b"1")]

    def publish() -> None:
        for channel, data in sent:
            context.buses.publish("lan", channel, data)

    context.executor.run_sync(recorder.start)
    context.executor.run_sync(publish)
    context.executor.run_sync(lambda: None)  # the deliveries queued by publish have run
    assert recorder.events == len(sent)
    recorder.stop()
    read = [(e.channel, e.data, e.timestamp, e.eventnum) for e in lcm.EventLog(str(path), "r")]
    assert [(channel, data) for channel, data, _, _ in read] == sent
    assert [n for _, _, _, n in read] == list(range(len(sent)))
    assert all(a[2] < b[2] for a, b in zip(read, read[1:], strict=False))
    reference = tmp_path / "reference.lcmlog"
    log = lcm.EventLog(str(reference), "w", overwrite=True)
    for channel, data, utime, _ in read:
        log.write_event(utime, channel, data)
    log.close()
    assert path.read_bytes() == reference.read_bytes()
    assert recorder.events == len(sent)  # still counted after the stop


def test_a_recorder_that_cannot_write_its_log_says_so(context: Context, tmp_path: Path) -> None:
    recorder = _recorder(context, tmp_path / "no such directory" / "run.lcmlog")
    with pytest.raises(AntalateError, match="cannot write the log"):
        context.executor.run_sync(recorder.on_start)


#: A process that records a stream and is killed (SIGKILL) without stopping: its log's ``argv[1]``.
_KILLED = """
STAMP = lambda i: 1_700_000_000_000_000 + 4000 * min(i + 1, 1000) + 4000 * max(0, i - 1999)
import os, signal, sys
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Context, NodeSettings
from antalate_lcm.runtime.recorder import LogRecorder

ctx = Context.in_process({"lan": "memq://"})
ctx.executor.start()
settings = NodeSettings.from_config(parse_config({"agent": {"name": "r"}, "buses": {"lan": "memq://"}}))
recorder = LogRecorder(settings, ctx, bus="lan", path=sys.argv[1])
clock = [0]
recorder.wallclock = lambda: clock[0] / 1e6
ctx.executor.run_sync(recorder.start)

def event(i):
    # 4 ms apart, then a burst of big events in one instant, then 4 ms apart again
    clock[0] = STAMP(i)
    ctx.buses.publish("lan", f"a{i % 7}/MC_STATE", bytes([i % 251]) * (300 if 1000 <= i < 2000 else 40))

for i in range(int(sys.argv[2])):
    ctx.executor.run_sync(lambda: event(i))  # recorded before the next (its own loop handle)
ctx.executor.run_sync(lambda: None)
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("events", [4000, 2000])
def test_a_killed_process_log_holds_every_event_older_than_lcm_loggers_flush_interval(
    tmp_path: Path, events: int
) -> None:
    """The bound lcm-logger keeps (lcm-logger/lcm_logger.c, --flush-interval, 100 ms): killed
    mid-stream, the log is the events in order up to a point, and every event stamped more than
    100 ms before the last one is in it. A slow stream (4 ms apart, 40 bytes) fills no buffer:
    only the time rule writes it (4 KiB held 200 ms of it). Killed at the end of a burst of
    events of one instant (``events`` 2000), no more than the buffer's bytes were held back."""
    import signal
    import subprocess
    import sys

    from antalate_lcm.runtime.recorder import FLUSH_AT, FLUSH_INTERVAL_US

    path = tmp_path / "killed.lcmlog"
    proc = subprocess.run(
        [sys.executable, "-c", _KILLED, str(path), str(events)], capture_output=True, check=False
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    read = [(e.eventnum, e.timestamp, len(e.data)) for e in lcm.EventLog(str(path), "r")]
    assert [n for n, _, _ in read] == list(range(len(read))), "a prefix of the events, in order"
    us = [1_700_000_000_000_000 + 4000 * min(i + 1, 1000) + 4000 * max(0, i - 1999) for i in range(events)]
    stamps = [int(t / 1e6 * 1e6) for t in us]  # the recorder's own arithmetic
    assert all(t == stamps[n] for n, t, _ in read)
    older = sum(1 for t in stamps if t < stamps[-1] - FLUSH_INTERVAL_US)
    assert older <= len(read) < events, "everything older is there; the last few are not"
    sizes = [28 + len("a0/MC_STATE") + (300 if 1000 <= i < 2000 else 40) for i in range(events)]
    assert path.stat().st_size > sum(sizes) - FLUSH_AT
