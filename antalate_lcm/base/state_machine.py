"""The one state-machine engine: typed rows, a table indexed by (state, event), guards over a read-only view.

The MC (`antalate_lcm.agent.mc.machine`) and the HLC (`antalate_lcm.agent.hlc.machine`) are each a table of `Row` s read
top to bottom: the first row whose source states hold the current state, whose event is the input and
whose guard (if any) is true wins. What a machine does with the winning row (its outcome type, its
actions, the bookkeeping of entering a state) stays in the machine; what every machine needs -- the row,
the lookup, the transition record -- is here, once.

Guards are typed against a view, a `typing.Protocol` of read-only properties the machine satisfies, not
against the machine: ``mypy --strict`` then rejects a guard that writes to the machine or reads a private
field (both happened when guards took the machine itself). At run time the view *is* the machine, so a
guard costs one call and no copy.

Pure logic: no I/O, no clock (the machines pass ``now`` in).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

StateT = TypeVar("StateT", bound=enum.Enum)
EventT = TypeVar("EventT", bound=enum.Enum)
#: What a guard may read of its machine: a Protocol of read-only properties.
ViewT = TypeVar("ViewT")
#: A machine's row type: `Row` itself, or a subclass that adds what the machine does on a row (the HLC's effects).
RowT = TypeVar("RowT", bound="Row[Any, Any, Any]")


@dataclass(frozen=True)
class Row(Generic[StateT, EventT, ViewT]):
    """One row: in any of `sources`, on `event`, if `guard` holds, go to `target` (None: stay, e.g. a refusal
    that only reports). `why` starts the transition's reason; `extra` marks a row beyond docs/design.md."""

    sources: frozenset[StateT]
    event: EventT
    target: StateT | None
    why: str
    guard: Callable[[ViewT], bool] | None = None
    extra: bool = False


@dataclass(frozen=True)
class Transition(Generic[StateT, EventT]):
    """A state change with its cause, for the node's log."""

    from_state: StateT
    to_state: StateT
    event: EventT
    reason: str
    at: float


class Table(Generic[StateT, EventT, ViewT, RowT]):
    """A machine's rows in priority order, indexed by (state, event).

    The index means a match reads a few rows rather than the table, and lets a machine skip deriving an
    event no row of its state takes (`events_taken`). A module builds its table once and every machine of the
    process shares it (a thousand agents' machines each indexing their own took 14 MiB).
    """

    __slots__ = ("rows", "_index", "_taken")

    def __init__(self, rows: Iterable[RowT]) -> None:
        self.rows: tuple[RowT, ...] = tuple(rows)
        index: dict[tuple[StateT, EventT], tuple[RowT, ...]] = {}
        for row in self.rows:
            for source in row.sources:
                index[(source, row.event)] = (*index.get((source, row.event), ()), row)
        self._index = index
        taken: dict[StateT, set[EventT]] = {}
        for state, event in index:
            taken.setdefault(state, set()).add(event)
        self._taken: dict[StateT, frozenset[EventT]] = {
            state: frozenset(events) for state, events in taken.items()
        }

    def __iter__(self) -> Iterator[RowT]:
        return iter(self.rows)

    def match(self, state: StateT, event: EventT, view: ViewT) -> RowT | None:
        """The first row of `state` taking `event` whose guard holds for `view` (the machine), or None."""
        for row in self._index.get((state, event), ()):
            if row.guard is None or row.guard(view):
                return row
        return None

    def events_taken(self, state: StateT) -> frozenset[EventT]:
        """The events some row of `state` takes, guards aside: an event outside it is not worth deriving
        (a set the machine tests membership in, so asking costs no call per event)."""
        return self._taken.get(state, frozenset())

    def sources_of(self, event: EventT) -> frozenset[StateT]:
        """Every state some row takes `event` in (e.g. for "accepted in …" rejection messages)."""
        return frozenset(state for row in self.rows if row.event is event for state in row.sources)
