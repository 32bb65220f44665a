"""The one way tests wait for something to happen: poll with a generous deadline, never a fixed sleep.

A loaded CI machine can be many times slower than a laptop, so a test states *what* it waits for and
a deadline far beyond the usual time; a pass returns as soon as the condition holds.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def wait_for(predicate: Callable[[], T], timeout: float = 10.0, interval: float = 0.02) -> T:
    """Poll ``predicate`` until it returns a truthy value (returned) or ``timeout`` s pass (its last,
    falsy value is returned: ``assert wait_for(...)`` fails with it)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(interval)
