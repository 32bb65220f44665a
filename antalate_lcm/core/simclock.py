"""Simulated time: an event loop whose clock moves only when nothing is left to do now.

``antalate run --speed`` (docs/experiments.md) runs a simulated swarm on a :class:`SimClock` instead
of the wall clock. The process's :class:`~antalate_lcm.core.executor.Executor` then runs a plain asyncio
selector loop (not uvloop: its clock cannot be replaced) whose ``time()`` is the simulated clock,
and whose selector never sleeps while the simulation runs: when no callback is ready and no
descriptor is readable, the clock jumps to the next timer's due time (lockstep: every timer due
at ``t``, and every message it sends, is handled before time moves past ``t``). A 10-minute
experiment takes as long as the process needs to compute it.

On this clock the executor runs timers on a grid of 50 ms (``_SIM_GRID_MS`` in
:mod:`antalate_lcm.core.executor`; for a period, or a one-shot's delay, that 50 ms does not divide,
the largest divisor of 50 ms that divides it, down to 1 ms). Every default period is a multiple of
50 ms and stays exact; an agent's phase within a period (``Node.first_delay``) is rounded up to the
grid, so the agents' timers fall on a few instants of each period instead of on every millisecond:
each distinct instant costs a loop iteration and, over several processes, a round between them.
Timers of one instant run in the order of their exact due times, so the seed's phases still order
the agents. The wall clock keeps its 1 ms slots and its spread phases (a thousand agents'
datagrams must not arrive at once).

Every node reads this one clock: ``Node.now`` and the behaviors' ``ctx.now`` (the executor's
``clock``), the sim adapter (constructed with that clock), message headers and the replay
window (the executor's ``wallclock``: a fixed epoch plus simulated time, so a run's bytes do not
depend on the day it ran).

``speed``: simulated seconds per real second at most (``math.inf``: as fast as the process can
compute). A run slower than that keeps its lockstep and simply takes longer (as a loaded wall-clock
run falls behind); a run on a held clock (:meth:`SimClock.hold`) waits, in real time, for events
from other threads and does not advance (the experiment holds it while its nodes start and after
the operator has finished, so what is recorded does not depend on how fast another thread is).

Over several processes (``antalate run --speed --processes P``) each one's clock has a ``coordinator``
(:class:`antalate_lcm.runtime.time_coordinator.ClockClient`): where a lone loop would move its clock,
it reports to the processes' coordinator and waits, and the coordinator moves it (and paces it).
"""

from __future__ import annotations

import asyncio
import math
import selectors
import time
from typing import Any, Protocol

#: Wall-clock time (s since 1970) of simulated time zero: fixed, so message headers, signatures
#: and logs are the same on every run (2027-01-15 08:00 UTC: no replay memory of a real flight
#: holds a time that late yet).
SIM_EPOCH = 1_800_000_000.0
#: Simulated monotonic time at the start: far from 0, as ``time.monotonic()`` is on a machine
#: that has been up a day (node code may use 0 for "never").
SIM_START = 100_000.0
#: Longest real wait (s) of a held clock between two looks at the loop's ready queue.
_HELD_WAIT = 0.05


class Coordinated(Protocol):
    """The clock of one of several processes on one simulated time
    (:class:`antalate_lcm.runtime.time_coordinator.ClockClient`): it moves only when told to."""

    def idle(self, next_due: float) -> bool:
        """The loop has nothing left to do now; its next timer is due at ``next_due``. True: the
        clock has moved or work is queued already (look again); False: wait for the answer."""
        ...


class SimClock:
    """Simulated seconds, advanced by a :class:`SimEventLoop` (and only by it), or, with a
    :attr:`coordinator`, by the processes' coordinator."""

    def __init__(self, speed: float = math.inf, *, held: bool = False) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0 (got {speed})")
        self.speed = speed
        self.t = SIM_START
        #: While held, time stands still and the loop waits for real events (see hold()).
        self.held = held
        self._real0 = time.monotonic()
        self._sim0 = SIM_START
        #: Several processes on this time (``--processes P``): the loop reports to it when idle and
        #: waits for its answer instead of moving time itself.
        self.coordinator: Coordinated | None = None

    def monotonic(self) -> float:
        """The executor's ``clock``: simulated seconds."""
        return self.t

    def wall(self) -> float:
        """The nodes' ``wallclock``: :data:`SIM_EPOCH` plus simulated seconds since the start."""
        return SIM_EPOCH + (self.t - SIM_START)

    @property
    def elapsed(self) -> float:
        """Simulated seconds since the start."""
        return self.t - SIM_START

    def hold(self) -> None:
        """Stop time (call on the loop thread): nothing due later runs until :meth:`release`."""
        self.held = True

    def release(self) -> None:
        """Let time run again (call on the loop thread, e.g. through ``Executor.call_soon``)."""
        self.held = False
        self._real0, self._sim0 = time.monotonic(), self.t

    def real_wait(self, by: float) -> float:
        """Real seconds to wait before moving time ``by`` s, so it runs at most ``speed`` times
        faster than real time (0 at ``max``, and for a run that has fallen behind)."""
        if math.isinf(self.speed):
            return 0.0
        return max(0.0, self._real0 + (self.t + by - self._sim0) / self.speed - time.monotonic())


class _SimSelector(selectors.BaseSelector):
    """The loop's selector: polls its descriptors without waiting, and when none is ready spends
    the loop's timeout (the time to its next timer) on the simulated clock instead of sleeping."""

    def __init__(self, clock: SimClock) -> None:
        self._clock = clock
        self._inner = selectors.DefaultSelector()

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._inner.register(fileobj, events, data)

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        return self._inner.unregister(fileobj)

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._inner.modify(fileobj, events, data)

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        clock = self._clock
        if timeout is None:  # nothing scheduled: only another thread can give the loop work
            if clock.coordinator is not None and not clock.held:  # ... or another process's message
                ready = self._inner.select(0)
                if ready:
                    return ready
                if clock.coordinator.idle(math.inf):
                    return []
            return self._inner.select(None)
        if clock.held:
            return self._inner.select(min(timeout, _HELD_WAIT))
        ready = self._inner.select(0)
        if ready or timeout <= 0:
            return ready
        client = clock.coordinator
        if client is not None:  # another process may yet send something for now: ask, then wait
            if client.idle(clock.t + timeout):
                return []
            return self._inner.select(None)
        wait = clock.real_wait(timeout)
        if wait > 0:  # --speed N: wait, yet wake for another thread's call (a stop, say)
            ready = self._inner.select(wait)
            if ready:
                return ready
        clock.t += timeout  # nothing to do before the next timer: it is its time
        return []

    def close(self) -> None:
        self._inner.close()

    def get_map(self) -> Any:
        return self._inner.get_map()


class SimEventLoop(asyncio.SelectorEventLoop):
    """An asyncio loop on simulated time (what :class:`~antalate_lcm.core.executor.Executor` runs with
    a :class:`SimClock`)."""

    def __init__(self, clock: SimClock) -> None:
        super().__init__(_SimSelector(clock))
        self.sim_clock = clock

    def time(self) -> float:
        return self.sim_clock.t
