"""``antalate log CONFIG -o flight.mcap`` (a bus straight to MCAP) and ``antalate export LOG -o
flight.mcap`` (an LCM log to MCAP): the flight in the file Foxglove and PlotJuggler open.

Recording reads the bus as any node does (the process's executor thread delivers each message with
the time it was heard, as ``lcm-logger`` stamps it) and writes on that thread, so the writer needs no
lock. Ctrl-C or SIGTERM ends the recording with the MCAP summary written: the file opens in a viewer
that seeks by its index.
"""

from __future__ import annotations

import argparse
import logging
import signal
import time
from pathlib import Path
from types import FrameType

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.mcap_log import McapLogWriter, export

log = logging.getLogger("antalate.mcap")


def _summary(writer: McapLogWriter) -> str:
    parts = [f"{writer.events} LCM events -> {writer.messages} MCAP messages"]
    if writer.view.unknown:
        kept = "kept raw" if writer.view.raw else "skipped (--raw keeps them)"
        parts.append(f"{sum(writer.view.unknown.values())} on non-antalate channels {kept}")
    if writer.view.undecodable:
        parts.append(f"{sum(writer.view.undecodable.values())} that did not decode")
    return "; ".join(parts)


def _open_output(path: str, force: bool) -> Path:
    out = Path(path)
    if out.exists() and not force:
        raise AntalateError(f"{out} exists: pass --force to overwrite it, or -o another file")
    return out


def record(url: str, out_path: str, *, channel: str = ".*", raw: bool = False, force: bool = False) -> int:
    """Record every ``channel`` message of the bus at ``url`` into an MCAP file until Ctrl-C/SIGTERM."""
    from antalate_lcm.core.bus import Buses

    out = _open_output(out_path, force)

    # The handler only raises a flag: setting an Event from a signal handler can deadlock the main
    # thread waiting on it (runtime/launch.py: run_until_signal), so the main thread polls.
    signalled: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        signalled.append(signum)

    previous = signal.signal(signal.SIGTERM, on_signal)
    buses = Buses({"log": url})
    try:
        buses.open()
        try:
            f = out.open("wb")
        except OSError as exc:
            raise AntalateError(f"cannot write {out}: {exc.strerror or exc}") from None
        with f:
            writer = McapLogWriter(f, raw=raw)

            def on_message(name: str, data: bytes) -> None:
                writer.write_event(name, time.time_ns(), data)

            buses.subscribe("log", channel, None, on_message, regex=True)
            print(f"logging {url} to {out} (MCAP); Ctrl-C stops", flush=True)
            try:
                while not signalled:
                    time.sleep(0.2)
            except KeyboardInterrupt:
                pass
            buses.close()  # no handler runs after this: the writer is ours alone
            writer.finish()
    finally:
        buses.close()
        signal.signal(signal.SIGTERM, previous)
    print(f"wrote {out}: {_summary(writer)}", flush=True)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from antalate_lcm.apps.analysis import check_log_file

    source = check_log_file(args.log)
    target = args.output or str(source.with_suffix(".mcap"))
    if Path(target).resolve() == source.resolve():
        raise AntalateError(f"{target} is the log itself: -o another file")
    out = _open_output(target, args.force)
    writer = export(source, out, raw=args.raw)
    print(f"wrote {out}: {_summary(writer)}")
    return 0


def export_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="LCM log file (lcm-logger, antalate log)")
    p.add_argument("-o", "--output", help="MCAP file (default: the log's name with .mcap)")
    p.add_argument("--raw", action="store_true", help="keep each message's LCM bytes too (raw/CHANNEL)")
    p.add_argument("-f", "--force", action="store_true", help="overwrite the MCAP file if it exists")
