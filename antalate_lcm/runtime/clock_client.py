"""A process's side of the shared simulated clock (:mod:`antalate_lcm.runtime.time_coordinator`): the
buses that cross processes made private (:func:`simulated_buses`, :class:`SimulatedBuses`), the client
that reports when the loop is idle and applies the coordinator's answers (:class:`ClockClient`; over
the coordinator's socket, :class:`SocketClockClient`, which :func:`join` starts in an agent process), and
the frames both sides write (the format is in the coordinator's docstring).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import signal
import socket
import struct
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.bus import Buses, Handler, Subscription
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.simclock import SimClock
from antalate_lcm.runtime.time_grant import (
    decode_messages,
    encode_interest,
    encode_message,
)
from antalate_lcm.transports import transport_for

log = logging.getLogger("antalate.simclock")

_FRAME = struct.Struct("<cQdI")
_HELLO, _INTEREST, _REPORT, _DELIVER, _ADVANCE = b"H", b"I", b"R", b"D", b"A"


def simulated_buses(buses: Mapping[str, str]) -> tuple[dict[str, str], list[str]]:
    """The buses of a process on the shared simulated clock, and those its client carries: each bus
    that crosses processes (its transport reaches other hosts: udpm, zenoh, ...) becomes a memq://
    bus of its own. Its own: ``memq://?``, ``memq://??`` ... (empty queries, which liblcm and the
    transport read as none) are other URLs to the bus, which keeps one connection per URL, so the connection
    never hears the agents' internal topics on the in-process ``memq://``."""
    crossing = sorted(name for name, url in buses.items() if transport_for(url).network_reachable)
    private = {name: "memq://" + "?" * (i + 1) for i, name in enumerate(crossing)}
    return {name: private.get(name, url) for name, url in buses.items()}, crossing


class SimulatedBuses(Buses):
    """The bus of a process on the shared clock: notes what its nodes subscribe to on the buses
    that cross processes, so that the coordinator hands it only those messages."""

    def __init__(self, urls: Mapping[str, str], crossing: Sequence[str]) -> None:
        super().__init__(urls)
        self._crossing = frozenset(crossing)
        #: (bus, channel, regex) subscribed since the client last said so.
        self.new_interest: list[tuple[str, str, bool]] = []

    def subscribe(
        self,
        bus: str,
        channel: str,
        msg_type: Any,
        handler: Handler,
        *,
        regex: bool = False,
        on_message: Callable[[Any], None] | None = None,
    ) -> Subscription:
        sub = super().subscribe(bus, channel, msg_type, handler, regex=regex, on_message=on_message)
        if bus in self._crossing:
            self.new_interest.append((bus, channel, regex))
        return sub


def _frame(kind: bytes, round_: int, value: float, payload: bytes = b"") -> bytes:
    return _FRAME.pack(kind, round_, value, len(payload)) + payload


def _frames(sock: socket.socket, buf: bytearray) -> list[tuple[bytes, int, float, bytes]]:
    """The frames readable now on ``sock`` (one ``recv`` for a whole frame, the usual case), after
    those begun in ``buf``; a frame begun is read to its end (its sender writes it whole)."""
    chunk = sock.recv(1 << 20)
    if not chunk:
        raise ConnectionError("the simulated clock's coordinator closed the connection")
    buf += chunk
    out = []
    while len(buf) >= _FRAME.size:
        kind, round_, value, size = _FRAME.unpack_from(buf)
        end = _FRAME.size + size
        while len(buf) < end:
            more = sock.recv(end - len(buf))
            if not more:
                raise ConnectionError("the simulated clock's coordinator closed the connection")
            buf += more
        out.append((kind, round_, value, bytes(buf[_FRAME.size : end])))
        del buf[:end]
    return out


class ClockClient:
    """A process's side: reports when its loop is idle, applies the coordinator's answers. This
    one reports over the coordinator's socket (an agent process); :class:`LocalClockClient` in the
    coordinator's own process."""

    def __init__(self, index: int, clock: SimClock) -> None:
        self.index = index
        self._clock = clock
        self._bus: SimulatedBuses | None = None
        #: Messages published here since the last report, encoded.
        self._outbox: list[bytes] = []
        #: Per bus: the others' messages published here by the client, not yet heard back.
        self._echo: dict[str, collections.deque[bytes]] = {}
        self._round = 0
        #: The next timer of the report awaiting its answer (None: no report waits).
        self._reported: float | None = None

    def bridge(self, bus: SimulatedBuses, names: Sequence[str]) -> None:
        """Carry every message published on ``names`` of ``bus`` (memq:// buses) to the others."""
        self._bus = bus
        for name in names:
            self._echo[name] = collections.deque()
            Buses.subscribe(bus, name, ".*", None, self._hearer(name), regex=True)  # not an interest

    def _hearer(self, name: str) -> Callable[[str, bytes], None]:
        echo = self._echo[name]
        outbox = self._outbox

        def heard(channel: str, data: bytes) -> None:
            # The others' messages come back here in the order the client published them, after
            # any message published here before them: the head is the next one to drop.
            if echo and echo[0] == data:
                echo.popleft()
                return
            outbox.append(encode_message(name, channel, data))

        return heard

    def idle(self, next_due: float) -> bool:
        """The loop has nothing left to do now; its next timer is at ``next_due``. A report waits
        for its answer unless this process has had work since (another thread's call): then the
        new report adds to it. True when the answer came at once (the loop looks again)."""
        if self._reported is not None and not self._outbox and next_due >= self._reported:
            return False
        payload = b"".join(self._outbox)
        self._outbox.clear()
        self._reported = next_due
        bus = self._bus
        interest = b""
        if bus is not None and bus.new_interest:  # what it now subscribes to, before what it sent
            interest = encode_interest(bus.new_interest)
            bus.new_interest.clear()
        return self._report(next_due, interest, payload)

    def _report(self, next_due: float, interest: bytes, payload: bytes) -> bool:
        raise NotImplementedError

    def apply(self, kind: bytes, round_: int, value: float, payload: bytes) -> None:
        """The coordinator's answer: move to ``value`` (an advance's time, or a delivery's: this
        process may have slept through advances), and deliver a delivery's messages."""
        self._round, self._reported = round_, None
        if value > self._clock.t:
            self._clock.t = value
        if kind == _DELIVER:
            bus = self._bus
            assert bus is not None
            for name, channel, data in decode_messages(payload):
                self._echo[name].append(data)
                bus.publish(name, channel, data)


class SocketClockClient(ClockClient):
    """An agent process's client: the coordinator is in the operator's process, over its socket."""

    def __init__(self, address: str, index: int, clock: SimClock) -> None:
        super().__init__(index, clock)
        self._address = address
        self._sock: socket.socket | None = None
        self._executor: Executor | None = None
        #: A frame from the coordinator begun, not yet whole.
        self._inbuf = bytearray()

    def start(self, executor: Executor) -> None:
        """Join the coordinator (before the loop runs); from now on the clock moves only by it."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.connect(self._address)
            sock.sendall(_frame(_HELLO, 0, float(self.index), str(os.getpid()).encode()))
        except OSError as exc:
            sock.close()
            raise AntalateError(f"cannot join the simulated clock at {self._address}: {exc}") from None
        self._sock, self._executor = sock, executor
        self._clock.coordinator = self
        executor.add_reader(sock.fileno(), self._readable)

    def _report(self, next_due: float, interest: bytes, payload: bytes) -> bool:
        sock = self._sock
        if sock is None:
            return False
        frame = _frame(_REPORT, self._round, next_due, payload)
        if interest:
            frame = _frame(_INTEREST, self._round, 0.0, interest) + frame
        try:
            sock.sendall(frame)
        except OSError:
            self._lost()
        return False

    def _readable(self) -> None:
        sock = self._sock
        if sock is None:
            return
        try:
            frames = _frames(sock, self._inbuf)
        except OSError:  # ConnectionError included: the coordinator is gone
            self._lost()
            return
        for frame in frames:
            self.apply(*frame)

    def _lost(self) -> None:
        """The coordinator is gone (the operator's process died): stop this process, as Ctrl-C."""
        if self._sock is None:
            return
        log.error("lost the simulated clock's coordinator; stopping this process")
        self.close()
        os.kill(os.getpid(), signal.SIGTERM)

    def close(self) -> None:
        sock, self._sock = self._sock, None
        self._clock.coordinator = None
        if sock is None:
            return
        if self._executor is not None:
            with contextlib.suppress(RuntimeError, ValueError):
                self._executor.remove_reader(sock.fileno())
        sock.close()


def join(
    address: str, index: int, clock: SimClock, bus: SimulatedBuses, executor: Executor, buses: Sequence[str]
) -> SocketClockClient:
    """An agent process on the shared clock: its crossing ``buses`` carried, its loop joined."""
    client = SocketClockClient(address, index, clock)
    client.bridge(bus, buses)
    client.start(executor)
    return client


__all__ = ["ClockClient", "SimulatedBuses", "SocketClockClient", "join", "simulated_buses"]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
