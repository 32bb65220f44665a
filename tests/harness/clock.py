"""A clock the test moves by hand, for code that takes a ``clock`` (a callable returning seconds)."""

from __future__ import annotations


class FakeClock:
    """Monotonic seconds that move only when told to (``advance``), from ``start``."""

    def __init__(self, start: float) -> None:
        self.t = start

    def __call__(self) -> float:
        return self.t

    def advance(self, seconds: float) -> None:
        self.t += seconds
