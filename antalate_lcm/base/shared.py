"""One instance per process of equal immutable values that every agent reads on every tick.

A thousand agents of one config each held their own copy of the same parameters (a machine's, a
sim's tuples, a behavior's params); at that size an agent's objects are out of the caches by its next
tick, so one object read by all of them is one cache line instead of a thousand (docs/simulator.md,
"Why a thousand agents cost more than twice what a hundred do, each").
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any, TypeVar

__all__ = ["shared_value"]

V = TypeVar("V")

#: Key -> the one instance kept for it (`shared_value`).
_SHARED: dict[Any, Any] = {}
#: Kept at most: a sweep of that many configurations in one process shares no more.
_LIMIT = 100_000


def shared_value(value: V, key: Hashable = None) -> V:
    """The process's one instance of ``value`` (immutable): the first one given for ``key``.

    ``key`` decides which values are one; by default the value itself (equal and hashable). A caller
    whose values may be equal without being the same to the bit (``0.0 == -0.0``, ``1 == 1.0``)
    passes a key that tells them apart, e.g. their ``repr``. An unhashable key raises TypeError."""
    k = value if key is None else key
    if len(_SHARED) >= _LIMIT:
        return _SHARED.get(k, value)  # type: ignore[no-any-return]
    return _SHARED.setdefault(k, value)  # type: ignore[no-any-return]
