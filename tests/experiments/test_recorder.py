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
