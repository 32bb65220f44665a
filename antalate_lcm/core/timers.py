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


#: Most runs in a ticker's cycle (`Ticker`): its groups' periods, in runs, whose least common
#: multiple is longer keep their due times (the defaults, 1, 2 and 4 runs, cycle in 4).
_MAX_CYCLE = 64

Jobs = tuple[Callable[[], Any], ...]


class Ticker:
    """The periodic jobs of one agent's nodes on one timer (`Node.ticker`): the HLC's control,
    telemetry and state (20, 10 and 5 Hz by default) and the MC's tick and state (10 and 5 Hz) are
    20 timer runs a second per agent, not 30 (one timer a node) nor 50 (one a job).

    The job at the timer's own rate (``base``, the first that came) runs on every run: the executor
    never runs a timer twice within its period, so it needs no due time. The other jobs are grouped
    by period, each group with its due time (a job joining a group runs on the group's runs): when
    a loaded executor skips runs, a group still runs at its rate on the runs that remain, as a
    timer of its own would, and a run before the next due time looks at no group. Each job's
    exception is logged on its own, by its node's log. Nodes come and go (`add`, `remove`), from
    the next run on: an MC whose HLC stopped keeps its jobs, and its watchdog of that HLC, on the
    same timer; a node stopped by a job of the run takes its jobs off that run's rest too.

    Between two runs the executor skips (`Timer.skips`; on simulated time it never does) the runs
    come one period apart, so each group runs on every n-th run, n its period in runs: the jobs of
    each run of that cycle (4 runs at the default rates) are one tuple, made from the due times
    when the cycle begins and run in turn with no due time looked at (a thousand agents' groups
    and their due times were 20 to 40 objects a run, each out of the caches by the agent's next
    run). After a skip, or a change of jobs, the due times are what they would be had they been
    kept, and a new cycle begins from them (after a skip, once a cycle's length of runs came with
    no other: a timer of a loop that keeps falling behind goes by its due times, with no cycle made
    for a run or two). A run at a ``now`` of the caller's goes by the due times.
    """

    # The first five are what a run of the cycle reads: one cache line of the object.
    __slots__ = (
        "cycle", "phase", "timer", "skips", "last",
        "hz", "period", "slack", "base", "base_owner", "base_log", "groups", "next_due", "length",
        "synced", "calm",
    )  # fmt: skip

    def __init__(self, hz: float) -> None:
        #: The jobs of each run while no run is skipped (None: none made since the last change).
        self.cycle: tuple[Jobs, ...] | None = None
        #: The `cycle`'s entry of the next run.
        self.phase = 0
        #: The executor's timer running `run` (set by whoever armed it).
        self.timer: Any = None
        #: The timer's `skips` when the cycle began (the same object: compared by identity).
        self.skips: object = None
        #: The due time of the cycle's last run.
        self.last = 0.0
        self.hz = hz
        #: The executor's timer period: what it adds to a due time for the next (`Executor._run_slot`).
        self.period = 1.0 / hz
        self.slack = 0.5 / hz  # a run a little early (the timer's millisecond slots) is on time
        self.base: Callable[[], Any] | None = None
        self.base_owner: object = None
        self.base_log: logging.Logger | None = None
        #: ``[period, due, [(fn, log, owner), ...]]`` per period of the other jobs, in the order they
        #: came; while a `cycle` runs, their due times are those of its beginning (`synced`).
        self.groups: list[list[Any]] = []
        #: The earliest due time of a group, less the slack: runs before it look at none.
        self.next_due = -math.inf
        #: Runs in a cycle of the groups' periods (0: longer than _MAX_CYCLE, the due times rule).
        self.length = 1
        #: The cycle's first run's time, and per group its first run in the cycle and its due time
        #: after that run.
        self.synced: tuple[float, list[tuple[int, float]]] = (0.0, [])
        #: Runs by the due times still to come, without a skip, before a cycle is made again.
        self.calm = 0

    def takes(self, jobs: list[tuple[float, Callable[[], Any]]]) -> bool:
        """Whether every one of ``jobs`` can run at its rate on this timer."""
        return all(divides(self.hz, rate) for rate, _ in jobs)

    def add(self, owner: object, jobs: list[tuple[float, Callable[[], Any]]], log: logging.Logger) -> None:
        """``owner``'s ``jobs`` (each rate dividing ``hz``: `takes`) from the next run on."""
        self._unsync()
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
        self.length = self._length()

    def remove(self, owner: object) -> bool:
        """Drop ``owner``'s jobs; True when none is left (the timer can go)."""
        self._unsync()
        if self.base_owner is owner:
            self.base = self.base_owner = self.base_log = None
        for group in self.groups:
            group[2] = [job for job in group[2] if job[2] is not owner]
        self.groups = [group for group in self.groups if group[2]]
        self.next_due = -math.inf
        self.length = self._length()
        return self.base is None and not self.groups

    def run(self, now: float | None = None) -> None:
        """One run of the timer, ``now`` the time it was due (None: the timer's due time, exact where
        the loop's clock is the one read when its iteration began: every slot of a backlog run in
        one iteration reads the same, and jobs then looked early and were skipped). The executor
        calls it as the timer's function, with no closure between."""
        cycle = self.cycle
        timer = self.timer
        if cycle is not None and now is None and timer.skips is self.skips:
            k = self.phase
            self.phase = k + 1 if k + 1 < len(cycle) else 0
            self.last = timer.due
        else:
            cycle = self._resync(now)
            if cycle is None:
                return
            k = 0
        for fn in cycle[k]:
            if self.cycle is not cycle and not self._holds(fn):
                continue  # its node stopped during this run
            try:
                fn()
            except Exception:
                self._failed(fn)

    def _resync(self, now: float | None) -> tuple[Jobs, ...] | None:
        """A run off the cycle: the cycle that begins with it (None: run by the due times)."""
        self._unsync()
        timer = self.timer
        if now is not None or not self.length:
            self._run_due(timer.due if now is None else now)
            return None
        if timer.skips is not self.skips:
            self.skips = timer.skips
            self.calm = self.length
        if self.calm:  # a timer that skips runs often goes on by the due times, with no cycle made
            self.calm -= 1
            self._run_due(timer.due)
            return None
        cycle = self._sync(timer.due)
        if cycle is None:
            self.calm = self.length
            self._run_due(timer.due)
        return cycle

    def _run_due(self, now: float) -> None:
        """A run by the groups' due times."""
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
                    if group[2] is not jobs and not self._holds(fn):
                        continue  # its node stopped during this run
                    try:
                        fn()
                    except Exception:
                        _log_raise(fn, log)
            if due < earliest:
                earliest = due
        self.next_due = earliest - slack

    def _sync(self, now: float) -> tuple[Jobs, ...] | None:
        """The cycle of runs from ``now`` on, made from the groups' due times as `_run_due` has
        them; its entry for ``now`` runs first (None: a group is not yet on its beat)."""
        period, slack = self.period, self.slack
        every: list[int] = []
        starts: list[tuple[int, float]] = []
        for group_period, due, _jobs in self.groups:
            n = round(group_period / period)
            # The group's first run from now: the first of the runs (the executor's sums) at or
            # past its due time less the slack, and its due time after it.
            t, first = now, 0
            while t < due - slack:
                t += period
                first += 1
                if first == n:
                    return None  # only a clock that went back
            after = due + group_period if t < due + group_period else t + group_period
            # Its next run n runs later, not before: a group behind (after a skip) catches up on
            # the runs in between first, by its due times.
            for _ in range(n - 1):
                t += period
            if t >= after - slack or t + period < after - slack:
                return None
            every.append(n)
            starts.append((first, after))
        base = () if self.base is None else (self.base,)
        runs = []
        for k in range(self.length):
            fns = list(base)
            for (first, _after), n, group in zip(starts, every, self.groups, strict=True):
                if (k - first) % n == 0:
                    fns.extend(fn for fn, _log, _owner in group[2])
            runs.append(tuple(fns))
        cycle = tuple(runs)
        self.cycle, self.phase, self.last, self.synced = cycle, 1 % self.length, now, (now, starts)
        return cycle

    def _unsync(self) -> None:
        """Back to the due times: each group's as `_run_due` would have kept it over the cycle."""
        if self.cycle is None:
            return
        begun, starts = self.synced
        period = self.period
        runs = round((self.last - begun) / period) + 1  # the cycle's runs so far
        for group, (first, after) in zip(self.groups, starts, strict=True):
            if runs > first:
                group[1] = after + (runs - 1 - first) // round(group[0] / period) * group[0]
        self.next_due = -math.inf
        self.cycle = None

    def _length(self) -> int:
        length = 1
        for group in self.groups:
            n = round(group[0] / self.period)
            length = length * n // math.gcd(length, n)
            if length > _MAX_CYCLE:
                return 0
        return length

    def _holds(self, fn: Callable[[], Any]) -> bool:
        return fn is self.base or any(job[0] is fn for group in self.groups for job in group[2])

    def _failed(self, fn: Callable[[], Any]) -> None:
        log = self.base_log if fn is self.base else None
        for group in self.groups:
            for job_fn, job_log, _owner in group[2]:
                if log is None and job_fn is fn:
                    log = job_log
        _log_raise(fn, log or logging.getLogger(__name__))
