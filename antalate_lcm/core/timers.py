"""Timer phasing and shared tickers: how a node's periodic work is spread over time and timers.

Pure (no I/O): :class:`~antalate_lcm.core.node.Node` asks :func:`phase_delay` where its periodic timers
start and hands :meth:`~antalate_lcm.core.node.Node.ticker`'s jobs to :func:`split_jobs` and
:func:`run_due`.
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


def split_jobs(
    hz: float, jobs: list[tuple[float, Callable[[], Any]]], log: logging.Logger
) -> tuple[list[list[Any]], list[tuple[float, Callable[[], Any]]]]:
    """``jobs`` (rate, fn) as the ones that share a ``hz`` timer (their rate divides it), each as
    ``[period, due, fn, log, owner]`` for :func:`run_due` (``log`` says what a raising ``fn`` did;
    ``owner`` is `Ticker.add`'s), and the ones that need a timer of their own."""
    shared: list[list[Any]] = []
    own: list[tuple[float, Callable[[], Any]]] = []
    for rate, fn in jobs:
        every = round(hz / rate)
        if every >= 1 and abs(hz / every - rate) <= 1e-9 * rate:
            shared.append([1.0 / rate, -math.inf, fn, log, None])
        else:
            own.append((rate, fn))
    return shared, own


def run_due(shared: list[list[Any]], now: float, slack: float) -> None:
    """Run the ``shared`` jobs whose period has come round at ``now`` (``slack`` early is on time);
    each job's exception is logged on its own, by its own log."""
    for job in shared:
        job_period, due, fn, log, _owner = job
        if now < due - slack:
            continue
        # As the executor re-arms a timer: the next period, or a period from now if behind.
        job[1] = due + job_period if now < due + job_period else now + job_period
        try:
            fn()
        except Exception:
            log.exception("%s raised; the node carries on", getattr(fn, "__qualname__", fn))


class Ticker:
    """The periodic jobs of one agent's nodes on one timer (`Node.ticker`): the HLC's control,
    telemetry and state (20, 10 and 5 Hz by default) and the MC's tick and state (10 and 5 Hz) are
    20 timer runs a second per agent, not 30 (one timer each) nor 50 (one per job).

    The job at the timer's own rate (``base``, the first that came) runs on every run: the executor
    never runs a timer twice within its period, so it needs no due time. Each other job keeps its
    own (`run_due`): when a loaded executor skips runs, a job still runs at its rate on the runs
    that remain, as a timer of its own would. Nodes come and go (`add`, `remove`): an MC whose HLC
    stopped keeps its jobs and its watchdog of that HLC on the same timer.
    """

    __slots__ = ("hz", "slack", "base", "base_owner", "base_log", "jobs", "timer")

    def __init__(self, hz: float) -> None:
        self.hz = hz
        self.slack = 0.5 / hz  # a run a little early (the timer's millisecond slots) is on time
        self.base: Callable[[], Any] | None = None
        self.base_owner: object = None
        self.base_log: logging.Logger | None = None
        #: ``[period, due, fn, log, owner]`` of every other job (`split_jobs`), in the order they came.
        self.jobs: list[list[Any]] = []
        #: The executor's timer running `run` (set by whoever armed it).
        self.timer: Any = None

    def takes(self, jobs: list[tuple[float, Callable[[], Any]]]) -> bool:
        """Whether every one of ``jobs`` can run at its rate on this timer."""
        return not split_jobs(self.hz, jobs, _LOG)[1]

    def add(self, owner: object, jobs: list[tuple[float, Callable[[], Any]]], log: logging.Logger) -> None:
        """``owner``'s ``jobs`` (each rate dividing ``hz``: `takes`) from the next run on."""
        shared, _ = split_jobs(self.hz, jobs, log)
        for job in shared:
            if self.base is None and abs(job[0] * self.hz - 1.0) <= 1e-9:
                self.base, self.base_owner, self.base_log = job[2], owner, log
            else:
                job[4] = owner
                self.jobs.append(job)

    def remove(self, owner: object) -> bool:
        """Drop ``owner``'s jobs; True when none is left (the timer can go)."""
        if self.base_owner is owner:
            self.base = self.base_owner = self.base_log = None
        self.jobs = [job for job in self.jobs if job[4] is not owner]
        return self.base is None and not self.jobs

    def run(self, now: float) -> None:
        """One run of the timer, ``now`` the time it was due."""
        base = self.base
        if base is not None:
            try:
                base()
            except Exception:
                assert self.base_log is not None
                self.base_log.exception("%s raised; the node carries on", getattr(base, "__qualname__", base))
        if self.jobs:
            run_due(self.jobs, now, self.slack)


_LOG = logging.getLogger("antalate.timers")
