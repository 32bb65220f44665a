"""One thread that runs every callback and timer of the nodes in a process.

Like rclpy's single-threaded executor: LCM dispatcher threads only decode and enqueue, so node code
(state machines, behaviors) runs on a single thread and needs no locks. A callback that raises is
logged and the executor carries on.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

log = logging.getLogger("antalate.executor")
T = TypeVar("T")


class Timer:
    """A periodic (or one-shot) callback; :meth:`cancel` stops it."""

    def __init__(self, period: float, fn: Callable[[], Any], *, oneshot: bool = False) -> None:
        self.period = period
        self.fn = fn
        self.oneshot = oneshot
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class Executor:
    def __init__(self, name: str = "antalate-executor", clock: Callable[[], float] = time.monotonic) -> None:
        self.name = name
        self.clock = clock
        self._calls: queue.SimpleQueue[tuple[Callable[..., Any], tuple[Any, ...]] | None] = queue.SimpleQueue()
        self._timers: list[tuple[float, int, Timer]] = []
        self._timers_lock = threading.Lock()
        self._order = itertools.count()
        self._running = False
        self._thread: threading.Thread | None = None
        #: Worst delay seen between a timer's due time and its run (s): the executor's headroom.
        self.max_timer_lag = 0.0
        self.callbacks_run = 0

    # ------------------------------------------------------------------ scheduling (any thread)
    def call_soon(self, fn: Callable[..., Any], *args: Any) -> None:
        self._calls.put((fn, args))

    def create_timer(self, period: float, fn: Callable[[], Any], *, first_delay: float | None = None) -> Timer:
        """Run ``fn`` every ``period`` s; the first run after ``first_delay`` (default: one period)."""
        if period <= 0:
            raise ValueError("timer period must be > 0")
        timer = Timer(period, fn)
        self._schedule(timer, self.clock() + (period if first_delay is None else first_delay))
        return timer

    def call_later(self, delay: float, fn: Callable[[], Any]) -> Timer:
        timer = Timer(delay, fn, oneshot=True)
        self._schedule(timer, self.clock() + delay)
        return timer

    def _schedule(self, timer: Timer, due: float) -> None:
        with self._timers_lock:
            heapq.heappush(self._timers, (due, next(self._order), timer))
        self._calls.put((_noop, ()))  # wake the loop so it recomputes its sleep

    def run_sync(self, fn: Callable[[], T], timeout: float = 10.0) -> T:
        """Run ``fn`` on the executor thread and return its result (for set-up, tests and shutdown)."""
        if threading.current_thread() is self._thread or not self._running:
            return fn()
        fut: Future[T] = Future()

        def call() -> None:
            try:
                fut.set_result(fn())
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                fut.set_exception(exc)

        self.call_soon(call)
        return fut.result(timeout)

    # ------------------------------------------------------------------ running
    def start(self) -> None:
        """Spin in a background thread."""
        if self._thread is not None:
            return
        self._running = True
        self._thread = threading.Thread(target=self._loop, name=self.name, daemon=True)
        self._thread.start()

    def spin(self) -> None:
        """Spin in the calling thread until :meth:`stop`."""
        self._running = True
        self._thread = threading.current_thread()
        self._loop()

    def stop(self) -> None:
        self._running = False
        self._calls.put(None)
        thread = self._thread
        if thread is not None and thread is not threading.current_thread() and thread.is_alive():
            thread.join(timeout=5)
        self._thread = None

    @property
    def running(self) -> bool:
        return self._running

    def _loop(self) -> None:
        while self._running:
            timeout = self._run_due_timers()
            try:
                item = self._calls.get(timeout=timeout)
            except queue.Empty:
                continue
            while item is not None:
                self._invoke(*item)
                try:
                    item = self._calls.get_nowait()
                except queue.Empty:
                    break
            if item is None and not self._running:
                break

    def _run_due_timers(self) -> float:
        while True:
            now = self.clock()
            with self._timers_lock:
                if not self._timers:
                    return 0.5
                due, _, timer = self._timers[0]
                if due > now:
                    return min(due - now, 0.5)
                heapq.heappop(self._timers)
            if timer.cancelled:
                continue
            self.max_timer_lag = max(self.max_timer_lag, now - due)
            self._invoke(timer.fn, ())
            if not timer.oneshot and not timer.cancelled:
                nxt = due + timer.period
                if nxt <= now:  # fell behind: skip missed runs rather than burst
                    nxt = now + timer.period
                with self._timers_lock:
                    heapq.heappush(self._timers, (nxt, next(self._order), timer))

    def _invoke(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.callbacks_run += 1
        try:
            fn(*args)
        except Exception:
            log.exception("callback %s raised; the executor carries on", getattr(fn, "__qualname__", fn))


def _noop() -> None:
    return None
