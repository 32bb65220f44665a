"""One simulated clock for the processes of ``antalate run --speed max|N --processes P``.

The operator's process (``antalate run``) serves a :class:`TimeCoordinator` on a Unix socket, on
its own loop; it and each agent process (``antalate agent --shard i/P --sim-clock ADDRESS``) run
their loop on a :class:`~antalate_lcm.core.simclock.SimClock` joined to it by a client
(:class:`LocalClockClient` in the operator's process, :class:`SocketClockClient` in an agent process, with the
rest of a process's side in :mod:`antalate_lcm.runtime.clock_client`). The rule
they follow is :mod:`antalate_lcm.runtime.time_grant` (why it keeps the lockstep and the run
deterministic is said there); here is only its I/O:

- Every bus that crosses processes (UDP multicast, Zenoh) becomes, in each process, a private
  memq:// bus of its own: a datagram through the kernel would arrive at a real moment, not a
  simulated one, and in an order set by the scheduler. The client hears every message published
  on it (a pattern subscription) and carries it in its next report, with what the process's
  nodes subscribed to on it since (:class:`SimulatedBuses`); the messages of the other processes
  it is handed come back on that bus, still at the time they were sent.
- A process reports when its loop has nothing left to do now (the simulated clock's selector
  calls :meth:`ClockClient.idle` where a lone process would move its clock), then waits on the
  coordinator's socket; its answer (deliver these, or move to ``t``) is read on the loop thread.
  The operator's process reports and is answered by calls, on its own loop: a round that only
  hands the recorder the agents' messages costs it no system call and no thread switch.
- A process whose socket closes before the run ends (it died, it was killed) stops the run: the
  coordinator says which one and at what simulated time (:attr:`TimeCoordinator.failure`), and
  sets :attr:`TimeCoordinator.lost` for ``antalate run`` to stop the others.
- A process that hangs (a behavior in an endless loop, a process stopped by SIGSTOP or a
  debugger) holds every other one, since time moves only once all have reported. A watchdog
  thread takes a process that owes a report for ``stall`` real seconds (``antalate run
  --stall-timeout``) as hung: it says which, stops the run the same way and kills that process
  (its pid came with its hello), which could not stop in order anyway.

The frames, both ways: kind (1 byte), round (u64), a float (a report's next timer, an answer's
time, a hello's process index), the payload's length (u32), the payload (messages; the
subscriptions of an interest frame, which precedes its report).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.simclock import SIM_START, SimClock
from antalate_lcm.runtime.clock_client import (
    _ADVANCE,
    _DELIVER,
    _HELLO,
    _INTEREST,
    _REPORT,
    ClockClient,
    SimulatedBuses,
    SocketClockClient,
    join,
    simulated_buses,
)

# The frame format, for the tests that forge frames (its home is clock_link).
from antalate_lcm.runtime.clock_client import _FRAME as _FRAME
from antalate_lcm.runtime.clock_client import _frame as _frame
from antalate_lcm.runtime.time_grant import (
    Deliver,
    Interest,
    Report,
    add_interest,
    decide,
    merge,
    pace,
    remaining,
    woken,
)

log = logging.getLogger("antalate.simclock")

#: Longest real wait (s) of the coordinator between two looks at whether it is being closed.
_PACE_STEP = 0.05
#: Real seconds an agent process may owe its report before the watchdog takes it as hung
#: (``antalate run --stall-timeout``): far above a round's cost (milliseconds at 1,000 agents,
#: seconds for a process swapped out on a loaded machine), far below a user giving up.
DEFAULT_STALL = 60.0


class LocalClockClient(ClockClient):
    """The client of the coordinator's own process (index 0): its reports and answers are calls."""

    def __init__(self, coordinator: TimeCoordinator, clock: SimClock) -> None:
        super().__init__(0, clock)
        self._coordinator = coordinator
        #: An answer came while this process reported.
        self._answered = False

    def _report(self, next_due: float, interest: bytes, payload: bytes) -> bool:
        self._answered = False
        self._coordinator.report(0, self._round, next_due, interest, payload)
        return self._answered

    def apply(self, kind: bytes, round_: int, value: float, payload: bytes) -> None:
        self._answered = True
        super().apply(kind, round_, value, payload)


class _Peer:
    __slots__ = ("sock", "index", "pid", "buf")

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.index: int | None = None
        #: From its hello: the watchdog kills a hung process.
        self.pid: int | None = None
        self.buf = bytearray()


class TimeCoordinator:
    """Serves :func:`~antalate_lcm.runtime.time_grant.decide` to ``count`` processes (index 0:
    this one, ``i + 1``: ``--shard i/P``) on a Unix socket in a temporary folder, on this
    process's own loop (:meth:`serve`): its reports and answers are calls, not messages, and a
    round that concerns only this process (the recorder given the agents' messages) costs no
    system call."""

    def __init__(self, count: int, speed: float = math.inf, stall: float = DEFAULT_STALL) -> None:
        self.count = count
        self.speed = speed
        self.stall = stall
        #: When the last round was decided (real, monotonic); None until the first one.
        self._progress: float | None = None
        self._dir = tempfile.mkdtemp(prefix="antalate-clock-")
        self.address = os.path.join(self._dir, "clock")
        self._server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._server.bind(self.address)
        self._server.listen(count)
        self._executor: Executor | None = None
        self._local: LocalClockClient | None = None
        self._peers: list[_Peer | None] = [None] * count
        self._pending: list[_Peer] = []  # connected, not yet said which process they are
        self._reports: list[Report | None] = [None] * count
        self._interests = [Interest() for _ in range(count)]
        #: Messages of reports that came after their round was decided: into the next one.
        self._carry: list[bytes] = [b""] * count
        self._round = 0
        #: The round each process was last woken in: its reports carry it.
        self._asked = [0] * count
        #: The current simulated time (the clocks' ``t``).
        self.t = SIM_START
        self._paced: tuple[float, float] | None = None
        #: Set when a process left before :meth:`finish`; :attr:`failure` says which and when.
        self.lost = threading.Event()
        self.failure = ""
        self._finished = False
        #: Rounds decided (deliveries and advances): what the shared clock costs (benchmarks/simtime.py).
        self.rounds = 0

    def serve(self, clock: SimClock, bus: SimulatedBuses, executor: Executor, buses: Sequence[str]) -> None:
        """Serve on ``executor``'s loop (before it runs), this process joined as index 0."""
        client = LocalClockClient(self, clock)
        client.bridge(bus, buses)
        self._local, self._executor = client, executor
        clock.coordinator = client
        executor.add_reader(self._server.fileno(), self._accept)
        threading.Thread(target=self._watch, name="clock-watchdog", daemon=True).start()

    def finish(self) -> None:
        """The run has ended: processes leaving now are stopping, not failing."""
        self._finished = True

    def close(self) -> None:
        """After the loop has stopped: the sockets and their folder."""
        self._finished = True
        for peer in [*self._peers, *self._pending]:
            if peer is not None:
                peer.sock.close()
        self._server.close()
        shutil.rmtree(self._dir, ignore_errors=True)

    # ------------------------------------------------------------------ on the loop
    def _accept(self) -> None:
        conn, _addr = self._server.accept()
        peer = _Peer(conn)
        self._pending.append(peer)
        assert self._executor is not None
        self._executor.add_reader(conn.fileno(), lambda: self._readable(peer))

    def _readable(self, peer: _Peer) -> None:
        if not self._read(peer):
            assert self._executor is not None
            self._executor.remove_reader(peer.sock.fileno())
            if peer in self._pending:
                self._pending.remove(peer)
            self._left(peer)
            return
        if peer.index is not None and peer in self._pending:
            self._pending.remove(peer)
        self._step()

    def report(self, index: int, round_: int, next_due: float, interest: bytes, payload: bytes) -> None:
        """Process ``index`` is idle (what it subscribed to since, what it sent); decide if all are."""
        if interest:
            add_interest(self._interests[index], interest)
        if round_ == self._asked[index]:
            self._reports[index] = merge(self._reports[index], Report(next_due, self._carry[index] + payload))
            self._carry[index] = b""
        else:  # a report of a round already decided: its messages go with the next one
            self._carry[index] += payload
        if index == 0:
            self._step()

    def _read(self, peer: _Peer) -> bool:
        try:
            chunk = peer.sock.recv(1 << 20)
        except OSError:
            return False
        if not chunk:
            return False
        peer.buf += chunk
        buf = peer.buf
        while len(buf) >= _FRAME.size:
            kind, round_, value, size = _FRAME.unpack_from(buf)
            end = _FRAME.size + size
            if len(buf) < end:
                break
            payload = bytes(buf[_FRAME.size : end])
            del buf[:end]
            if kind == _HELLO:
                index = int(value)
                if not 0 < index < self.count or self._peers[index] is not None:
                    log.error("the simulated clock refused a process calling itself %d", index)
                    return False
                peer.index = index
                self._peers[index] = peer
                peer.pid = int(payload) if payload.isdigit() else None
            elif kind == _INTEREST and peer.index is not None:
                # At once: its report may come in a later read (a thousand agents' subscriptions
                # are more than one read), and it must be known before that report is.
                add_interest(self._interests[peer.index], payload)
            elif kind == _REPORT and peer.index is not None:
                self.report(peer.index, round_, value, b"", payload)
        return True

    def _left(self, peer: _Peer) -> None:
        peer.sock.close()
        if peer.index is not None:
            self._peers[peer.index] = None
        if self._finished or self.lost.is_set():  # already stopping (the watchdog killed it): said
            return
        who = f"agent process {peer.index} of {self.count - 1}"
        if peer.index is None:
            who = "a process that never said which it was"
        self.failure = (
            f"{who} left the simulated clock at {self.t - SIM_START:.3f} s of simulated time "
            "(it died, or was killed); the run stops"
        )
        log.error("%s", self.failure)
        self.lost.set()

    def _step(self) -> None:
        """Decide the round if every process has reported, and answer the processes it wakes."""
        if self.lost.is_set():
            return
        decision = decide(self._reports, self._interests)
        if decision is None:
            return
        self._round += 1
        self.rounds += 1
        self._progress = time.monotonic()
        wake = woken(decision)
        self._reports = remaining(self._reports, decision)
        for i in wake:
            self._asked[i] = self._round
        if isinstance(decision, Deliver):
            for i in wake:
                self._answer(i, _DELIVER, self.t, decision.batches[i])
            return
        self._pace(decision.t)
        self.t = decision.t
        for i in wake:
            self._answer(i, _ADVANCE, decision.t, b"")

    def _pace(self, t: float) -> None:
        """``--speed N``: time runs at most N times real time from the first grant on (the loop
        waits: every process is idle, nothing else can happen before ``t``)."""
        if math.isinf(self.speed):
            return
        if self._paced is None:
            self._paced = (time.monotonic(), self.t)
        real0, sim0 = self._paced
        while not self._finished and (wait := pace(self.speed, real0, sim0, t, time.monotonic())) > 0:
            time.sleep(min(wait, _PACE_STEP))
            self._progress = time.monotonic()  # waiting on purpose, not on a process

    def _watch(self) -> None:
        """The watchdog (its own thread): a round not decided for ``stall`` s names the processes
        that owe their report, stops the run and kills them. It counts from the first round on,
        so a slow start (a thousand agents' nodes, time held) is not taken for a hang."""
        step = min(1.0, self.stall / 4)
        while not (self._finished or self.lost.is_set()):
            time.sleep(step)
            since = self._progress
            if since is None or time.monotonic() - since < self.stall or self._finished:
                continue
            reports, peers = self._reports, self._peers
            owing = [
                peer
                for report, peer in zip(reports[1:], peers[1:], strict=True)
                if report is None and peer is not None
            ]
            if not owing:  # this process itself is busy (it cannot be waiting on itself): not a hang
                continue
            names = ", ".join(self._named(peer) for peer in owing)
            self.failure = (
                f"{names} sent nothing for {self.stall:g} s of real time at {self.t - SIM_START:.3f} s "
                "of simulated time (it hangs or was stopped, and every other process waits for it; "
                "--stall-timeout sets how long); the run stops and it is killed"
            )
            log.error("%s", self.failure)
            self.lost.set()
            for peer in owing:
                if peer.pid is not None:
                    with contextlib.suppress(OSError):
                        os.kill(peer.pid, signal.SIGKILL)
            return

    def _named(self, peer: _Peer) -> str:
        pid = f" (pid {peer.pid})" if peer.pid is not None else ""
        return f"agent process {peer.index} of {self.count - 1}{pid}"

    def _answer(self, index: int, kind: bytes, value: float, payload: bytes) -> None:
        if index == 0:
            assert self._local is not None
            self._local.apply(kind, self._round, value, payload)
            return
        peer = self._peers[index]
        if peer is None:
            return
        try:
            peer.sock.sendall(_frame(kind, self._round, value, payload))
        except OSError:  # its end is closed: its read says so next
            log.debug("cannot send to process %s", index)


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)


__all__ = [
    "DEFAULT_STALL",
    "ClockClient",
    "LocalClockClient",
    "SimulatedBuses",
    "SocketClockClient",
    "TimeCoordinator",
    "join",
    "simulated_buses",
]
