"""The executor runs callbacks and timers on one thread and survives a raising callback."""

from __future__ import annotations

import threading
import time

import pytest

from antalate_lcm.executor import Executor
from tests.netns import wait_for


@pytest.fixture
def ex() -> Executor:
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
