"""The process's one event loop: every LCM socket, timer and node callback runs on its thread.

Like rclpy's wait set, the loop waits on every LCM instance's file descriptor (``lcm.fileno()``),
its timers and a wake-up for other threads, and calls ``handle()`` when a descriptor is readable:
a message reaches its node's handler on the loop thread with no hop through a queue, and node code
(state machines, behaviors) runs on a single thread and needs no locks. Blocking work (a vehicle
adapter's I/O) runs on worker threads that post their results back with :meth:`Executor.call_soon`.

It is an asyncio loop (uvloop when installed: measured in ``benchmarks/bus.py``, it dispatches a
datagram faster than a selector loop written in Python), so asyncio code can share it through
:attr:`Executor.loop` (the OSC's HTTP exchange does); coroutines still running when the executor stops
are cancelled and given a moment to unwind. A callback that raises is logged and the loop carries on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import operator
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from antalate_lcm.core.simclock import SimClock

log = logging.getLogger("antalate.executor")
#: Timers are run in 1 ms slots: those due in the same millisecond share one loop handle (a
#: thousand simulated agents start in the same tick, so their same-period timers stay together),
#: which saves a handle and a heap entry per timer run; a timer runs at most 1 ms after its time.
_SLOTS_PER_S = 1000
#: A timer of period ``p`` runs in a slot that is a multiple of ``p / _QUANTUM_PER_PERIOD`` ms (1 to
#: _MAX_QUANTUM_MS): a thousand agents' 20 Hz and 10 Hz timers then share 200 loop iterations a
#: second, not 1,000, each with one wait, one drain of the sockets and one delivery of in-process
#: messages for five times as many timers (a fifth of an agent process's loop overhead), and a
#: timer runs at most a tenth of its period (5 ms at most) after its time; short timers keep 1 ms.
_QUANTUM_PER_PERIOD = 10
_MAX_QUANTUM_MS = 5
#: On simulated time timers run on a grid of 50 ms (for a period, or a one-shot's delay, that 50 ms
#: does not divide: the largest divisor of 50 ms that divides it in whole ms; else 1 ms). Every
#: default period is a multiple of 50 ms (HLC control 20 Hz, telemetry 10 Hz, the nodes' 5 Hz
#: republish, the behaviors' 10 Hz and 5 Hz ticks, the HLC's 0.25 s and the BMA's 5 s sweeps, the
#: operator's 0.1 s and the faults' 0.05 s steps) and stays exact: only an agent's phase
#: (``Node.first_delay``) is rounded up, by less than one step. On the wall clock the phases spread
#: a thousand agents' datagrams over every millisecond; on simulated time they only made distinct
#: instants, each an iteration of the loop and, over ``--processes P``, a round or two between the
#: processes: 1,800 rounds per simulated second for 100 agents, 2,000 for 1,000, against 40 on the
#: grid (docs/experiments.md). Timers of one instant run in the order of their exact due times, so
#: the phases (and the seed that draws them) still order the agents.
_SIM_GRID_MS = 50
#: ms of float error (a due time summed from simulated seconds) not taken for a later slot.
_SIM_SLACK_MS = 1e-3
#: Timers run between two polls of the urgent readers (:meth:`Executor.add_reader`): a slot of a
#: thousand agents' timers takes tens of milliseconds, longer than a socket's buffer lasts.
_POLL_EVERY = 64
#: A timer's due time, read in C (a slot of a thousand agents' timers is sorted by it).
_DUE = operator.attrgetter("due")
#: One float object per period of the periodic timers (a few: the agents' rates), so a slot of a
#: thousand agents' timers adds the same object to each due time, read once into the caches, not a
#: thousand copies of it each out of them; bounded, as periods could be made up.
_PERIODS: dict[float, float] = {}
_MAX_PERIODS = 256
#: s the coroutines left on a stopping loop have to unwind once cancelled (see _finish_tasks).
_UNWIND_S = 2.0
T = TypeVar("T")


def new_event_loop() -> asyncio.AbstractEventLoop:
    """uvloop when installed (it comes with uvicorn[standard]), else asyncio's own loop."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - uvloop is a dependency; plain asyncio still works
        return asyncio.new_event_loop()
    return uvloop.new_event_loop()


def _finish_tasks(loop: asyncio.AbstractEventLoop) -> None:
    """Cancel the coroutines still on a stopped loop and let them unwind (as ``asyncio.run`` does):
    a node's HTTP exchange closes its connections instead of being destroyed pending."""
    tasks = asyncio.all_tasks(loop)
    if not tasks:
        return
    for task in tasks:
        task.cancel()
    done, pending = loop.run_until_complete(asyncio.wait(tasks, timeout=_UNWIND_S))
    for task in pending:
        log.warning(
            "coroutine %s did not finish within %.0f s of the executor's stop", task.get_name(), _UNWIND_S
        )
    for task in done:
        if not task.cancelled() and task.exception() is not None:
            log.error("coroutine %s raised", task.get_name(), exc_info=task.exception())


def _whole_ms(period: float) -> int:
    """``period`` in ms when it is a whole number of them (0 otherwise)."""
    ms = period * _SLOTS_PER_S
    whole = round(ms)
    return whole if whole >= 1 and abs(ms - whole) < _SIM_SLACK_MS else 0


def _sim_grid(period: float) -> int:
    """The slots (ms) a timer of ``period`` runs on, on simulated time (see _SIM_GRID_MS)."""
    whole = _whole_ms(period)
    return math.gcd(whole, _SIM_GRID_MS) if whole else 1


class Timer:
    """A periodic (or one-shot) callback; :meth:`cancel` stops it (from any thread)."""

    __slots__ = ("period", "fn", "oneshot", "cancelled", "due", "quantum", "step", "skips")

    def __init__(
        self, period: float, fn: Callable[[], Any], *, oneshot: bool = False, lockstep: bool = False
    ) -> None:
        if not oneshot and len(_PERIODS) < _MAX_PERIODS:
            period = _PERIODS.setdefault(float(period), float(period))
        self.period = period
        self.fn = fn
        self.oneshot = oneshot
        self.cancelled = False
        self.due = 0.0
        #: Slots (ms) its runs are rounded up to a multiple of (see _QUANTUM_PER_PERIOD); on simulated
        #: time (``lockstep``) the grid of _SIM_GRID_MS that keeps its period exact.
        self.quantum = (
            _sim_grid(period)
            if lockstep
            else max(1, min(_MAX_QUANTUM_MS, int(period * _SLOTS_PER_S / _QUANTUM_PER_PERIOD)))
        )
        #: On simulated time, its period in whole ms (0: not whole, or the wall clock): its next slot
        #: is this many after the last, counted in integers, so float sums never push a run a step late.
        self.step = _whole_ms(period) if lockstep else 0
        #: Runs it fell a period or more behind and skipped (a `Ticker` then re-reads its due times).
        self.skips = 0

    def cancel(self) -> None:
        # A flag, checked before each run: asyncio's handles are not thread-safe, and a cancelled
        # timer's slot in the loop lapses at its next due time anyway.
        self.cancelled = True


class Executor:
    """One event loop on one thread: LCM descriptors, timers and callbacks of a process's nodes."""

    def __init__(
        self,
        name: str = "antalate-executor",
        clock: Callable[[], float] = time.monotonic,
        *,
        sim: SimClock | None = None,
    ) -> None:
        self.name = name
        #: Simulated time (``antalate run --speed``, :mod:`antalate_lcm.core.simclock`): the loop, its
        #: timers, ``clock`` and ``wallclock`` all run on it. None: the wall clock, on uvloop.
        self.sim = sim
        #: What nodes read as ``now`` (timers themselves run on the loop's monotonic clock).
        self.clock = clock if sim is None else sim.monotonic
        #: What nodes stamp their headers with and check the replay window against.
        self.wallclock: Callable[[], float] = time.time if sim is None else sim.wall
        self._loop = self._new_loop()
        self._readers: dict[int, Callable[[], None]] = {}
        #: Readers that are also called between timers of a long slot (they must never block).
        self._urgent: tuple[Callable[[], None], ...] = ()
        #: Timers by due slot (see _SLOTS_PER_S): one loop handle per slot, not one per timer run.
        self._slots: dict[int, list[Timer]] = {}
        self._thread: threading.Thread | None = None
        self._ident: int | None = None
        self._started = False
        self._running = False
        #: Worst delay seen between a timer's due time and its run (s): the executor's headroom.
        self.max_timer_lag = 0.0

    def _new_loop(self) -> asyncio.AbstractEventLoop:
        if self.sim is None:
            return new_event_loop()
        from antalate_lcm.core.simclock import SimEventLoop

        return SimEventLoop(self.sim)

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The asyncio loop (for coroutines that belong with the nodes: run them with
        ``asyncio.run_coroutine_threadsafe(coro, executor.loop)``)."""
        return self._loop

    def on_loop(self) -> bool:
        """True on the loop's thread (or before the loop runs): its structures may be touched directly."""
        return self._ident == threading.get_ident() or not self._started

    # ------------------------------------------------------------------ scheduling (any thread)
    def call_soon(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` on the loop thread, after what is already queued (in call order)."""
        loop = self._loop
        try:
            if self.on_loop():
                loop.call_soon(self._invoke, fn, args)
            else:
                loop.call_soon_threadsafe(self._invoke, fn, args)
        except RuntimeError:
            # The loop is closed: the process is shutting down, like a call queued after stop().
            log.debug("dropped %s: the executor is stopped", getattr(fn, "__qualname__", fn))

    def create_timer(
        self, period: float, fn: Callable[[], Any], *, first_delay: float | None = None
    ) -> Timer:
        """Run ``fn`` every ``period`` s; the first run after ``first_delay`` (default: one period)."""
        if period <= 0:
            raise ValueError("timer period must be > 0")
        timer = Timer(period, fn, lockstep=self.sim is not None)
        self._schedule(timer, period if first_delay is None else first_delay)
        return timer

    def call_later(self, delay: float, fn: Callable[[], Any]) -> Timer:
        timer = Timer(delay, fn, oneshot=True, lockstep=self.sim is not None)
        self._schedule(timer, delay)
        return timer

    def _schedule(self, timer: Timer, delay: float) -> None:
        if self.on_loop():
            self._arm(timer, self._loop.time() + max(delay, 0.0))
        else:
            self.call_soon(lambda: self._arm(timer, self._loop.time() + max(delay, 0.0)))

    def _arm(self, timer: Timer, due: float) -> None:
        if timer.cancelled:
            return
        timer.due = due
        q = timer.quantum
        ms = due * _SLOTS_PER_S
        slot = -(-math.ceil(ms if self.sim is None else ms - _SIM_SLACK_MS) // q) * q
        timers = self._slots.get(slot)
        if timers is not None:
            timers.append(timer)
            return
        try:
            self._loop.call_at(slot / _SLOTS_PER_S, self._run_slot, slot)
        except RuntimeError:
            log.debug("timer not armed: the executor is stopped")
            return
        self._slots[slot] = [timer]

    def _run_slot(self, slot: int) -> None:
        # Runs ~50 timers per simulated agent-second: the timer's run and its re-arm are inlined,
        # and what every timer of the slot shares is read once (the lag is written once, the
        # slot most of them go to next is kept at hand).
        timers = self._slots.pop(slot, [])
        if self.sim is not None and len(timers) > 1:
            timers.sort(key=_DUE)  # an instant of the grid: in the order of their exact times
        loop = self._loop
        slots = self._slots
        now = loop.time()
        urgent = self._urgent if len(timers) > _POLL_EVERY else ()
        n = 0
        lag = self.max_timer_lag
        ceil = math.ceil
        last, same = -1, timers  # (no slot is -1: the first timer sets both)
        for timer in timers:
            if urgent:
                n += 1
                if n == _POLL_EVERY:
                    n = 0
                    for poll in urgent:
                        self._invoke(poll, ())
            if timer.cancelled:
                continue
            due = timer.due
            if now - due > lag:
                lag = now - due
            try:
                timer.fn()
            except Exception:
                log.exception(
                    "callback %s raised; the executor carries on",
                    getattr(timer.fn, "__qualname__", timer.fn),
                )
            if timer.oneshot or timer.cancelled:
                continue
            nxt = due + timer.period
            if nxt <= now:  # fell behind: skip missed runs rather than burst
                nxt = now + timer.period
                timer.skips += 1
            timer.due = nxt
            step = timer.step
            if step:
                k = slot + step
            else:
                q = timer.quantum
                k = -(-ceil(nxt * _SLOTS_PER_S) // q) * q
            if k != last:
                last = k
                found = slots.get(k)
                if found is None:
                    found = slots[k] = []
                    loop.call_at(k / _SLOTS_PER_S, self._run_slot, k)
                same = found
            same.append(timer)
        self.max_timer_lag = lag

    def run_sync(self, fn: Callable[[], T], timeout: float = 10.0) -> T:
        """Run ``fn`` on the loop thread and return its result (for set-up, tests and shutdown)."""
        if self._ident == threading.get_ident() or not self._running:
            return fn()
        fut: Future[T] = Future()

        def call() -> None:
            try:
                fut.set_result(fn())
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                fut.set_exception(exc)

        self.call_soon(call)
        return fut.result(timeout)

    # ------------------------------------------------------------------ file descriptors
    def add_reader(self, fd: int, callback: Callable[[], None], *, urgent: bool = False) -> None:
        """Call ``callback`` on the loop thread whenever ``fd`` is readable (an LCM ``fileno()``).

        ``urgent``: also call it between the timers of a long slot, readable or not (it must return
        at once when nothing waits): a socket read only by this loop (udpm_socket) would otherwise
        overflow its kernel buffer while a thousand agents' timers run.
        """
        self._readers[fd] = callback
        if urgent:
            self._urgent = (*self._urgent, callback)
        if self.on_loop():
            self._loop.add_reader(fd, callback)
        else:
            self.run_sync(lambda: self._loop.add_reader(fd, callback))

    def remove_reader(self, fd: int) -> None:
        callback = self._readers.pop(fd, None)
        if callback is None:
            return
        self._urgent = tuple(c for c in self._urgent if c is not callback)
        if self._loop.is_closed():
            return
        if self.on_loop():
            self._loop.remove_reader(fd)
        else:
            self.run_sync(lambda: self._loop.remove_reader(fd))

    # ------------------------------------------------------------------ running
    def start(self) -> None:
        """Run the loop in a background thread."""
        if self._thread is not None:
            return
        self._prepare()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def _prepare(self) -> None:
        if self._loop.is_closed():  # restarted after stop(): a fresh loop, the same descriptors
            self._loop = self._new_loop()
            self._slots.clear()  # their handles died with the old loop (as a timer did before slots)
            for fd, callback in self._readers.items():
                self._loop.add_reader(fd, callback)
        self._started = self._running = True

    def _run(self) -> None:
        loop = self._loop
        self._ident = threading.get_ident()
        asyncio.set_event_loop(loop)
        try:
            loop.run_forever()
            _finish_tasks(loop)
        finally:
            self._ident = None
            self._started = self._running = False
            asyncio.set_event_loop(None)
            for fd in self._readers:
                loop.remove_reader(fd)
            loop.close()

    def stop(self) -> None:
        """Stop the loop and join its thread (from any thread, the loop's own included); coroutines
        still on the loop are cancelled first and unwind on its thread (see _finish_tasks)."""
        self._running = False
        thread = self._thread
        loop = self._loop
        if thread is None:
            if not loop.is_closed() and not loop.is_running():
                _finish_tasks(loop)  # created by nodes started before the loop ever ran
                loop.close()
            return
        if self._ident == threading.get_ident():
            loop.stop()  # _run closes the loop when the current callback returns
            self._thread = None
            return
        with contextlib.suppress(RuntimeError):  # already closed
            loop.call_soon_threadsafe(loop.stop)
        if thread is not threading.current_thread() and thread.is_alive():
            thread.join(timeout=5)
        self._thread = None

    def _invoke(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            fn(*args)
        except Exception:
            log.exception("callback %s raised; the executor carries on", getattr(fn, "__qualname__", fn))
