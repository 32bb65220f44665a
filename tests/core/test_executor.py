"""The executor runs callbacks and timers on one thread and survives a raising callback."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator

import lcm
import pytest

from antalate_lcm.core.executor import Executor
from antalate_lcm.core.simclock import SimClock
from tests.harness.polling import wait_for


def handle_pending(lc: lcm.LCM) -> None:
    """A reader's callback: what is waiting on ``lc``, without blocking the loop."""
    lc.handle_timeout(0)


@pytest.fixture
def ex() -> Iterator[Executor]:
    e = Executor()
    e.start()
    yield e
    e.stop()


def test_callbacks_run_on_one_thread_in_order(ex: Executor) -> None:
    seen: list[tuple[int, str]] = []
    for i in range(100):
        ex.call_soon(lambda i=i: seen.append((i, threading.current_thread().name)))
    assert wait_for(lambda: len(seen) == 100, 2)
    assert [i for i, _ in seen] == list(range(100))
    assert {name for _, name in seen} == {"antalate-executor"}


def test_periodic_timer_and_cancel(ex: Executor) -> None:
    ticks: list[float] = []
    timer = ex.create_timer(0.02, lambda: ticks.append(time.monotonic()))
    assert wait_for(lambda: len(ticks) >= 10, 2)
    timer.cancel()
    n = len(ticks)
    time.sleep(0.1)
    assert len(ticks) <= n + 1
    gaps = [b - a for a, b in zip(ticks, ticks[1:], strict=False)]
    assert 0.01 < sum(gaps) / len(gaps) < 0.04


def test_raising_callback_does_not_stop_the_executor(ex: Executor) -> None:
    done = threading.Event()

    def boom() -> None:
        raise RuntimeError("boom")

    ex.call_soon(boom)
    ex.call_soon(done.set)
    assert done.wait(2)


def test_run_sync_returns_and_raises(ex: Executor) -> None:
    assert ex.run_sync(lambda: threading.current_thread().name) == "antalate-executor"
    with pytest.raises(ZeroDivisionError):
        ex.run_sync(lambda: 1 / 0)


def test_stop_joins_the_thread() -> None:
    e = Executor(name="short-lived")
    e.start()
    e.create_timer(0.01, lambda: None)
    e.stop()
    assert "short-lived" not in {t.name for t in threading.enumerate()}


def test_a_readable_descriptor_is_handled_on_the_loop_thread(ex: Executor) -> None:
    """The wait set: an LCM instance's fileno() is watched and handle() runs on the loop thread."""
    import lcm

    lc = lcm.LCM("memq://")
    seen: list[tuple[bytes, str]] = []
    lc.subscribe("C", lambda _ch, data: seen.append((data, threading.current_thread().name)))
    ex.add_reader(lc.fileno(), lambda: handle_pending(lc))
    for i in range(50):
        lc.publish("C", bytes([i]))
    assert wait_for(lambda: len(seen) == 50, 2)
    assert [d for d, _ in seen] == [bytes([i]) for i in range(50)]
    assert {name for _, name in seen} == {"antalate-executor"}
    ex.remove_reader(lc.fileno())
    lc.publish("C", b"late")
    time.sleep(0.1)
    assert len(seen) == 50, "a removed descriptor is no longer handled"


def test_timers_created_from_another_thread_run_on_the_loop(ex: Executor) -> None:
    names: list[str] = []
    done = threading.Event()

    def schedule() -> None:
        def record() -> None:
            names.append(threading.current_thread().name)
            done.set()

        ex.call_later(0.01, record)

    worker = threading.Thread(target=schedule)
    worker.start()
    worker.join()
    assert done.wait(2)
    assert names == ["antalate-executor"]


def test_a_timer_cancelled_before_it_is_due_never_runs(ex: Executor) -> None:
    ran: list[int] = []
    timer = ex.call_later(0.05, lambda: ran.append(1))
    timer.cancel()
    time.sleep(0.15)
    assert ran == []


def test_stop_from_a_callback_and_calls_after_stop_are_dropped() -> None:
    """A node may stop the process from inside a callback; a worker posting later must not raise."""
    e = Executor(name="self-stopping")
    e.start()
    e.run_sync(lambda: None)
    e.call_soon(e.stop)
    assert wait_for(lambda: "self-stopping" not in {t.name for t in threading.enumerate()}, 2)
    e.call_soon(lambda: None)  # the loop is closed: dropped, no exception
    e.call_later(0.01, lambda: None)
    assert e.run_sync(lambda: 42) == 42  # not running: runs in the caller


def test_restart_after_stop_watches_the_same_descriptors() -> None:
    import lcm

    lc = lcm.LCM("memq://")
    got: list[bytes] = []
    lc.subscribe("C", lambda _ch, data: got.append(data))
    e = Executor()
    e.add_reader(lc.fileno(), lambda: handle_pending(lc))
    e.start()
    lc.publish("C", b"1")
    assert wait_for(lambda: got == [b"1"], 2)
    e.stop()
    e.start()
    lc.publish("C", b"2")
    assert wait_for(lambda: got == [b"1", b"2"], 2)
    e.stop()


def test_an_urgent_reader_is_polled_between_the_timers_of_a_long_slot(ex: Executor) -> None:
    """A thousand agents' timers due in one millisecond run as one slot; a socket that only this
    loop reads (the own udpm reader) is read between them, not only when the slot is over."""
    import socket

    quiet, other = socket.socketpair()  # never readable: only the polls between timers call it
    order: list[str] = []
    done = threading.Event()
    try:
        ex.add_reader(quiet.fileno(), lambda: order.append("poll"), urgent=True)

        def make() -> None:  # one loop callback: the same loop time, so one slot
            for _ in range(300):
                ex.call_later(0.05, lambda: order.append("timer"))
            ex.call_later(0.2, done.set)

        ex.run_sync(make)
        assert done.wait(5)
        timers = [i for i, what in enumerate(order) if what == "timer"]
        assert len(timers) == 300
        between = order[timers[0] : timers[-1]]
        assert between.count("poll") >= 3, order  # one poll per 64 timers at least
        ex.remove_reader(quiet.fileno())
        before = len(order)
        done.clear()
        ex.run_sync(make)
        assert done.wait(5)
        assert order[before:].count("poll") == 0  # removed: no longer polled
    finally:
        quiet.close()
        other.close()


@pytest.mark.parametrize("ran", [True, False], ids=["running", "never-started"])
def test_coroutines_left_at_stop_are_cancelled_and_unwind(ran: bool) -> None:
    """A node's coroutine (the OSC's HTTP exchange) gets to close what it holds when the executor
    stops, instead of being destroyed pending."""
    ex = Executor()
    unwound: list[str] = []

    async def holds_a_connection() -> None:
        unwound.append("started")
        try:
            await asyncio.sleep(3600)
        finally:
            await asyncio.sleep(0)  # unwinding may await (closing a connection does)
            unwound.append(threading.current_thread().name)

    if ran:
        ex.start()
    task = ex.run_sync(lambda: ex.loop.create_task(holds_a_connection()))
    if ran:
        assert wait_for(lambda: unwound == ["started"], 2)
    ex.stop()
    # a coroutine that never ran took nothing to release: cancelled before its first line
    assert unwound == (["started", "antalate-executor"] if ran else [])
    assert task.cancelled()


def test_on_simulated_time_timers_share_a_50_ms_grid_and_keep_their_periods() -> None:
    """Ten agents' 10 Hz timers at ten phases run at two instants of each period, in the order of
    their phases; a 30 ms period and a 23 ms one-shot, which 50 ms does not divide, keep their times."""
    clock = SimClock()
    ex = Executor(sim=clock)
    runs: list[tuple[str, float]] = []

    def at(name: str) -> Callable[[], None]:
        return lambda: runs.append((name, round(clock.elapsed, 6)))

    for i in range(10):  # first due 100 ms (a0) down to 14.5 ms (a9)
        ex.create_timer(0.1, at(f"a{i}"), first_delay=0.1 - 0.0095 * i)
    ex.create_timer(0.03, at("odd"))
    ex.call_later(0.023, at("once"))
    ex.call_later(1.01, ex.stop)
    ex.start()
    assert wait_for(lambda: not ex.loop.is_running() and clock.elapsed > 1.0, 30)
    agents = [(name, t) for name, t in runs if name.startswith("a")]
    assert sorted({t for _, t in agents}) == [round(0.05 * k, 6) for k in range(1, 21)]
    assert [name for name, t in agents if t == 0.05] == ["a9", "a8", "a7", "a6"]
    assert [name for name, t in agents if t == 0.1] == ["a5", "a4", "a3", "a2", "a1", "a0"]
    for i in range(10):
        times = [t for name, t in agents if name == f"a{i}"]
        assert times == [round(times[0] + 0.1 * k, 6) for k in range(10)]
    assert [t for name, t in runs if name == "odd"] == [round(0.03 * k, 6) for k in range(1, 34)]
    assert [t for name, t in runs if name == "once"] == [0.023]
