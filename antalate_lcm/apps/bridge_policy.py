"""What the bridge remembers and counts, pure (no I/O, time passed in): the messages it has carried
(:class:`Memory`, against echoes and a second bridge's copies), the newest-wins rate caps
(:class:`Throttle`), each direction's limits and counters (:class:`Direction`), and the origin tags
that stop a message going back to the bus it came from (docs/wan.md)."""

from __future__ import annotations

import hashlib
import re
from collections import OrderedDict
from dataclasses import dataclass, field

from antalate_lcm.apps.bridge_config import DEFAULT_MAX_SIZE

#: Seen messages remembered at most (each ~100 bytes), whatever arrives within ``memory`` seconds.
MAX_REMEMBERED = 100_000


class Memory:
    """(channel, digest) pairs seen in the last ``window`` seconds, ``limit`` at most. Not thread-safe."""

    def __init__(self, window: float, limit: int = MAX_REMEMBERED) -> None:
        self.window = window
        self.limit = limit
        self._seen: OrderedDict[bytes, float] = OrderedDict()

    @staticmethod
    def digest(channel: str, data: bytes) -> bytes:
        h = hashlib.blake2b(data, digest_size=16, person=b"antalate-bridge")
        h.update(channel.encode())
        return h.digest()

    def prune(self, now: float) -> None:
        """Forget what left the window (oldest first, O(1) per entry); also when nothing arrives."""
        seen = self._seen
        while seen:
            oldest, t = next(iter(seen.items()))
            if now - t <= self.window:
                break
            del seen[oldest]

    def check_and_add(self, key: bytes, now: float) -> bool:
        """True (and remembered afresh) if ``key`` was seen within the window, else remember it."""
        self.prune(now)
        seen = key in self._seen
        self._seen[key] = now
        self._seen.move_to_end(key)
        if len(self._seen) > self.limit:  # a flood within one window: the oldest goes first
            self._seen.popitem(last=False)
        return seen

    def __len__(self) -> int:
        return len(self._seen)


class Throttle:
    """Newest-wins rate cap per channel: at most one message per ``1/rate`` s, the latest one."""

    def __init__(self, rate: float) -> None:
        self.interval = 1.0 / rate
        self._last: dict[str, float] = {}
        self._pending: dict[str, bytes] = {}
        #: Messages replaced by a newer one before their slot.
        self.superseded = 0

    def offer(self, channel: str, data: bytes, now: float) -> bool:
        """True: send now. False: kept as the channel's newest, sent by :meth:`due`."""
        last = self._last.get(channel)
        if last is None or now - last >= self.interval:
            self._last[channel] = now
            self._pending.pop(channel, None)
            return True
        if channel in self._pending:
            self.superseded += 1
        self._pending[channel] = data
        return False

    def due(self, now: float) -> list[tuple[str, bytes]]:
        out = []
        for channel in list(self._pending):
            if now - self._last[channel] >= self.interval:
                out.append((channel, self._pending.pop(channel)))
                self._last[channel] = now
        return out

    def prune(self, now: float) -> None:
        """Forget the slots of channels that have nothing waiting and whose slot has passed."""
        stale = [c for c, t in self._last.items() if now - t >= self.interval and c not in self._pending]
        for channel in stale:
            del self._last[channel]

    def __len__(self) -> int:
        return len(self._last)


@dataclass
class Direction:
    """What goes from one side to the other: the caps, the size limits and the counters."""

    source: str
    dest: str
    limits: list[tuple[re.Pattern[str], Throttle]]
    sizes: list[tuple[re.Pattern[str], int]] = field(default_factory=list)
    max_size: int = DEFAULT_MAX_SIZE
    forwarded: int = 0
    #: Messages on channels ``[bridge] channels``/``exclude`` leave out.
    not_selected: int = 0
    #: Not forwarded, and rightly: already carried (an echo, a second bridge's copy), brought from
    #: the destination by another bridge, or another bridge of the site forwards this way.
    seen: int = 0
    same_origin: int = 0
    standby: int = 0
    #: LCM payload bytes received from ``source`` and sent to ``dest``.
    bytes_in: int = 0
    bytes_out: int = 0
    #: Messages not forwarded, by reason (see :data:`DROP_REASONS`).
    dropped: dict[str, int] = field(default_factory=dict)

    def throttle_for(self, channel: str) -> Throttle | None:
        for pattern, throttle in self.limits:
            if pattern.fullmatch(channel):
                return throttle
        return None

    def size_limit(self, channel: str) -> int:
        for pattern, limit in self.sizes:
            if pattern.fullmatch(channel):
                return limit
        return self.max_size

    @property
    def largest(self) -> int:
        """The largest message any channel may carry this way (what reassembly may ever hold)."""
        return max([self.max_size, *(limit for _, limit in self.sizes)])


#: Why a message was not forwarded (stats keys ``dropped_<reason>``).
DROP_REASONS = {
    "bad_channel": "its channel cannot be carried by LCM (empty, a NUL byte, over 63 bytes)",
    "oversize": "it is over the size limit of its channel",
    "damaged": "it is not LCM or is damaged (LAN datagrams, or fragments that never all came)",
    "send_error": "the destination refused it",
    "error": "an unforeseen error while forwarding it",
}


def origin_tag(name: str) -> bytes:
    """A short tag naming a bus of a site (the same on every bridge that joins that bus)."""
    return hashlib.blake2b(name.encode(), digest_size=6).hexdigest().encode()


__all__ = ["DROP_REASONS", "MAX_REMEMBERED", "Direction", "Memory", "Throttle", "origin_tag"]
