"""Run a set of nodes until SIGINT/SIGTERM, then stop them in reverse order and close the bus."""

from __future__ import annotations

import gc
import logging
import signal
import threading
import time
from collections.abc import Callable, Sequence
from concurrent import futures
from functools import partial
from types import FrameType

from antalate_lcm.core.node import Context, Node

log = logging.getLogger("antalate.launch")

#: Nodes started per hop to the loop (a few ms of work; the loop runs its timers in between).
START_BATCH = 64
#: s for every node of the process to stop (a thousand simulated agents on a loaded machine).
STOP_TIMEOUT = 120.0


def wait_for_stop(stop: threading.Event | None = None) -> None:
    """Block the main thread until SIGINT/SIGTERM or ``stop`` is set (what ``antalate bridge`` and
    ``antalate router`` do while their own threads work). The handlers only note the signal, for
    the reason given in :func:`run_until_signal`, and the previous ones are put back."""
    stop = stop or threading.Event()
    signalled: list[int] = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, _frame: signalled.append(signum))
    try:
        while not (signalled or stop.is_set()):
            time.sleep(0.2)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def run_until_signal(
    context: Context,
    nodes: Sequence[Node],
    *,
    stop_event: threading.Event | None = None,
    poll: Callable[[], bool] | None = None,
    started_all: Callable[[], None] | None = None,
) -> int:
    """Start ``nodes`` and block until a signal, ``stop_event`` or ``poll()`` returning True.

    The bus is opened before any node starts so a missing multicast route is reported up front.
    ``started_all`` is called (on this thread) once every node has started: simulated time is
    released there, so no node's timers ran while the others were still starting.
    """
    stop = stop_event or threading.Event()
    # The handler only raises a flag: it runs on the main thread between two bytecodes, possibly
    # inside `Event.wait`, whose condition lock is not re-entrant -- `stop.set()` there deadlocked
    # the process for good (a SIGTERM'd HLC that never exited). The main thread polls instead.
    signalled: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        signalled.append(signum)

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    started: list[Node] = []
    try:
        context.buses.open()
        context.executor.start()

        # A hop to the loop per batch of nodes, not per node: a thousand agents' nodes each waited
        # for their turn behind the timers of those already running (STANDBY came late), and one
        # hop for all would hold the loop for seconds.
        def start_batch(batch: Sequence[Node]) -> None:
            for node in batch:
                node.start()
                started.append(node)

        # No collection while they start: what the start builds lives as long as the process, yet
        # the collector walked it all, again and again as it grew (three full collections, 0.35 s
        # of a 1,000-agent start, a thirtieth of a 10 s simulated mission's CPU).
        collecting = gc.isenabled()
        gc.disable()
        try:
            for i in range(0, len(nodes), START_BATCH):
                context.executor.run_sync(
                    partial(start_batch, nodes[i : i + START_BATCH]), timeout=STOP_TIMEOUT
                )
        finally:
            # ... and out of its sight after, so a full collection does not walk a thousand
            # agents' nodes (2 x 130 ms in 10 s measured with 1,000 simulated agents, a pause every
            # agent of the process felt).
            gc.freeze()
            if collecting:
                gc.enable()
        if started_all is not None:
            started_all()
        # Waiting on the event (never set by the handler) wakes the moment another thread sets it.
        while not (signalled or stop.wait(0.2)):
            if poll is not None and poll():
                break
        if signalled:
            log.info("received %s, stopping", signal.Signals(signalled[0]).name)
        return 0
    finally:

        def stop_all() -> None:
            for node in reversed(started):
                try:
                    node.stop()
                except Exception:
                    log.exception("stopping %s failed", node.name)

        # One hop to the loop for all of them (not one per node: a thousand agents' nodes would
        # each wait for their turn behind the swarm's timers); on_stop may block, hence the time.
        try:
            context.executor.run_sync(stop_all, timeout=STOP_TIMEOUT)
        except (TimeoutError, futures.TimeoutError):  # one class from Python 3.11 on
            log.error("the nodes did not stop within %.0f s; closing the bus anyway", STOP_TIMEOUT)
        context.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
