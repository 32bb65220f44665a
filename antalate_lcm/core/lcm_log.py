"""LCM log files (what ``lcm-logger`` and ``antalate log`` write), read the one way the analysis, the
MCAP conversion and the replay check all need: opening one says what is wrong in an ``AntalateError``,
and its events come as ``(timestamp µs, channel, data)`` with the channel always text.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import lcm

from antalate_lcm.base.errors import AntalateError


def open_log(path: str | Path) -> lcm.EventLog:
    """``path`` opened for reading; a missing file, a directory or a non-log is an ``AntalateError``."""
    try:
        return lcm.EventLog(str(path), "r")
    except (OSError, RuntimeError, ValueError) as exc:
        raise AntalateError(f"{path}: cannot be opened as an LCM log: {exc}") from None


def log_events(log: lcm.EventLog) -> Iterator[tuple[int, str, bytes]]:
    """The events of ``log`` from where it stands to its end or its first damage (liblcm stops there:
    ``log.tell()`` then says where). liblcm gives a channel that is not UTF-8 as bytes; it comes here
    decoded with replacement characters, so one odd name cannot stop a reader."""
    while (event := log.read_next_event()) is not None:
        channel = event.channel
        if isinstance(channel, bytes):
            channel = channel.decode("utf-8", "replace")
        yield int(event.timestamp), channel, bytes(event.data)
