"""Record every channel of one bus to an LCM log from inside a process (``antalate run -o``).

The file is what ``lcm-logger`` writes (``lcm.EventLog``), so ``antalate analyze``, ``lcm-logplayer``
and the ``file://`` provider read it. Recording inside the process, rather than starting
``lcm-logger`` beside it, also works on ``memq://`` (one process, no multicast route needed) and
misses nothing at the start: the subscription exists before the first agent node starts.
"""

from __future__ import annotations

import lcm

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.bus import Subscription
from antalate_lcm.core.node import Context, Node, NodeSettings


class LogRecorder(Node):
    """A node that writes every message heard on ``bus`` (its channel, bytes and arrival time on the
    nodes' wall clock: simulated with ``antalate run --speed``)."""

    kind = "recorder"

    def __init__(self, settings: NodeSettings, context: Context, *, bus: str, path: str) -> None:
        super().__init__(settings, context, name="recorder")
        self.bus = bus
        self.path = path
        self.events = 0
        self._log: lcm.EventLog | None = None
        self._sub: Subscription | None = None

    def on_start(self) -> None:
        try:
            self._log = lcm.EventLog(self.path, "w", overwrite=True)
        except (OSError, RuntimeError, ValueError) as exc:
            raise AntalateError(f"cannot write the log {self.path}: {exc}") from None
        self._sub = self.context.buses.subscribe(self.bus, ".*", None, self._write, regex=True)

    def _write(self, channel: str, data: bytes) -> None:  # on the executor's loop thread
        if self._log is not None:
            self._log.write_event(int(self.wallclock() * 1e6), channel, data)
            self.events += 1

    def on_stop(self) -> None:
        if self._sub is not None:
            self.context.buses.unsubscribe(self._sub)
            self._sub = None
        if self._log is not None:
            self._log.close()
            self._log = None
