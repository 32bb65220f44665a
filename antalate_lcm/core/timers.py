"""Timer phasing and shared tickers: how a node's periodic work is spread over time and timers.

Pure (no I/O): :class:`~antalate_lcm.core.node.Node` asks :func:`phase_delay` where its periodic timers
start and puts :meth:`~antalate_lcm.core.node.Node.ticker`'s jobs on a :class:`Ticker` (one per agent).
"""

from __future__ import annotations

import logging
import math
import zlib
from collections.abc import Callable
from typing import Any

#: Phases a period is split into to spread the agents' periodic timers (`phase_delay`).
PHASES = 1000


def phase_delay(period: float, agent: str, seed: int | None) -> float:
    """When a periodic timer of ``agent`` first runs: within one ``period``, at a phase fixed
    by the agent's name, so a thousand agents started together do not all run in the same tick
    (one of 1,000 phases, so a period's runs spread over its every millisecond: 16 phases sent
    a thousand agents' datagrams in bursts that overflowed receive buffers; an agent's nodes
    share their phase). With a run ``seed`` (``Context.seed``) the phase is drawn from it as well:
    another seed starts the agents in another order, as agents switched on by hand would be."""
    name = agent if seed is None else f"{seed}/{agent}"
    return period * (1.0 - (zlib.crc32(name.encode()) % PHASES) / PHASES)


def divides(hz: float, rate: float) -> bool:
    """Whether a job at ``rate`` can run on a ``hz`` timer: every whole number of its runs."""
    every = round(hz / rate)
    return every >= 1 and abs(hz / every - rate) <= 1e-9 * rate


def _log_raise(fn: Callable[[], Any], log: logging.Logger) -> None:
    log.exception("%s raised; the node carries on", getattr(fn, "__qualname__", fn))


class Ticker:
    """The periodic jobs of one agent's nodes on one timer (`Node.ticker`): the HLC's control,
    telemetry and state (20, 10 and 5 Hz by default) and the MC's tick and state (10 and 5 Hz) are
    20 timer runs a second per agent, not 30 (one timer a node) nor 50 (one a job).

    The job at the timer's own rate (``base``, the first that came) runs on every run: the executor
    never runs a timer twice within its period, so it needs no due time. The other jobs are grouped
    by period, each group with its due time (a job joining a group runs on the group's runs): when
    a loaded executor skips runs, a group still runs at its rate on the runs that remain, as a
    timer of its own would, and a run before the next due time looks at no group. Each job's
    exception is logged on its own, by its node's log. Nodes come and go (`add`, `remove`): an MC
    whose HLC stopped keeps its jobs, and its watchdog of that HLC, on the same timer.
    """

    __slots__ = ("hz", "slack", "base", "base_owner", "base_log", "groups", "next_due", "timer")

    def __init__(self, hz: float) -> None:
        self.hz = hz
        self.slack = 0.5 / hz  # a run a little early (the timer's millisecond slots) is on time
        self.base: Callable[[], Any] | None = None
        self.base_owner: object = None
        self.base_log: logging.Logger | None = None
        #: ``[period, due, [(fn, log, owner), ...]]`` per period of the other jobs, in the order they came.
        self.groups: list[list[Any]] = []
        #: The earliest due time of a group, less the slack: runs before it look at none.
        self.next_due = -math.inf
        #: The executor's timer running `run` (set by whoever armed it).
        self.timer: Any = None

    def takes(self, jobs: list[tuple[float, Callable[[], Any]]]) -> bool:
        """Whether every one of ``jobs`` can run at its rate on this timer."""
        return all(divides(self.hz, rate) for rate, _ in jobs)

    def add(self, owner: object, jobs: list[tuple[float, Callable[[], Any]]], log: logging.Logger) -> None:
        """``owner``'s ``jobs`` (each rate dividing ``hz``: `takes`) from the next run on."""
        for rate, fn in jobs:
            period = 1.0 / rate
            if self.base is None and abs(rate - self.hz) <= 1e-9 * rate:
                self.base, self.base_owner, self.base_log = fn, owner, log
                continue
            group = next((g for g in self.groups if abs(g[0] - period) <= 1e-9 * period), None)
            if group is None:
                group = [period, -math.inf, []]
                self.groups.append(group)
                self.next_due = -math.inf
            group[2].append((fn, log, owner))

    def remove(self, owner: object) -> bool:
        """Drop ``owner``'s jobs; True when none is left (the timer can go)."""
        if self.base_owner is owner:
            self.base = self.base_owner = self.base_log = None
        for group in self.groups:
            group[2] = [job for job in group[2] if job[2] is not owner]
        self.groups = [group for group in self.groups if group[2]]
        self.next_due = -math.inf
        return self.base is None and not self.groups

    def run(self, now: float | None = None) -> None:
        """One run of the timer, ``now`` the time it was due (None: the timer's due time, exact where
        the loop's clock is the one read when its iteration began: every slot of a backlog run in
        one iteration reads the same, and jobs then looked early and were skipped). The executor
        calls it as the timer's function, with no closure between."""
        if now is None:
            now = self.timer.due
        base = self.base
        if base is not None:
            try:
                base()
            except Exception:
                _log_raise(base, self.base_log)  # type: ignore[arg-type]
        if now < self.next_due:
            return
        slack = self.slack
        earliest = math.inf
        for group in self.groups:
            period, due, jobs = group
            if now >= due - slack:
                # As the executor re-arms a timer: the next period, or a period from now if behind.
                due = group[1] = due + period if now < due + period else now + period
                for fn, log, _owner in jobs:
                    try:
                        fn()
                    except Exception:
                        _log_raise(fn, log)
            if due < earliest:
                earliest = due
        self.next_due = earliest - slack
