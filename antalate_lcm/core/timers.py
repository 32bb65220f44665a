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
    hz: float, jobs: list[tuple[float, Callable[[], Any]]]
) -> tuple[list[list[Any]], list[tuple[float, Callable[[], Any]]]]:
    """``jobs`` (rate, fn) as the ones that share a ``hz`` timer (their rate divides it), each as
    ``[period, due, fn]`` for :func:`run_due`, and the ones that need a timer of their own."""
    shared: list[list[Any]] = []
    own: list[tuple[float, Callable[[], Any]]] = []
    for rate, fn in jobs:
        every = round(hz / rate)
        if every >= 1 and abs(hz / every - rate) <= 1e-9 * rate:
            shared.append([1.0 / rate, -math.inf, fn])
        else:
            own.append((rate, fn))
    return shared, own


def run_due(shared: list[list[Any]], now: float, slack: float, log: logging.Logger) -> None:
    """Run the ``shared`` jobs whose period has come round at ``now`` (``slack`` early is on time);
    each job's exception is logged on its own."""
    for job in shared:
        job_period, due, fn = job
        if now < due - slack:
            continue
        # As the executor re-arms a timer: the next period, or a period from now if behind.
        job[1] = due + job_period if now < due + job_period else now + job_period
        try:
            fn()
        except Exception:
            log.exception("%s raised; the node carries on", getattr(fn, "__qualname__", fn))
