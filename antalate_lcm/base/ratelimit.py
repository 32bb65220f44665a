"""Log a recurring problem once per key per period; limit a rate per key.

A flood of garbage datagrams or a dead link must be visible in the log without drowning it, and one
sender's flood must spend its own budget, not everyone's (the station, the bridge, the web console).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Hashable


class RateLimitedLog:
    def __init__(
        self, logger: logging.Logger, period: float = 60.0, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._logger = logger
        self._period = period
        self._clock = clock
        self._last: dict[Hashable, float] = {}
        self._suppressed: dict[Hashable, int] = {}
        self._lock = threading.Lock()

    def log(self, key: Hashable, level: int, msg: str, *args: object) -> bool:
        """Log unless ``key`` was logged less than ``period`` ago; return whether it was logged."""
        now = self._clock()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self._period:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return False
            self._last[key] = now
            suppressed = self._suppressed.pop(key, 0)
        if suppressed:
            msg += " (%d more like this since the last report)"
            args = (*args, suppressed)
        self._logger.log(level, msg, *args)
        return True


class TokenBucket:
    """Rate limits by key: ``rate`` per second sustained, ``burst`` at once.

    ``take`` returns 0 when allowed, else the seconds until one more is allowed (Retry-After).
    Full buckets are forgotten by `sweep`, so memory follows the active keys, not every address
    that ever knocked.
    """

    def __init__(self, rate: float, burst: float) -> None:
        self.rate = rate
        self.burst = burst
        self._buckets: dict[Hashable, tuple[float, float]] = {}

    def take(self, key: Hashable, now: float, cost: float = 1.0) -> float:
        """``cost`` units (a byte count for a bandwidth cap) now, or the seconds until they would be."""
        level, last = self._buckets.get(key, (self.burst, now))
        level = min(self.burst, level + (now - last) * self.rate)
        if level < cost:
            self._buckets[key] = (level, now)
            return (cost - level) / self.rate
        self._buckets[key] = (level - cost, now)
        return 0.0

    def sweep(self, now: float) -> None:
        full = [
            k for k, (level, last) in self._buckets.items() if level + (now - last) * self.rate >= self.burst
        ]
        for k in full:
            del self._buckets[k]

    def __len__(self) -> int:
        return len(self._buckets)
