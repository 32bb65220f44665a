"""The bus: named LCM instances with typed publish/subscribe, read by the process's event loop.

A bus is routed by its name only: its URL goes to :func:`antalate_lcm.transports.transport_for`,
which picks the transport by the URL's scheme and opens it; the bus asks that transport what it
needs to know (whether antalate reads it from its own socket, whether it stays in the process).

How it uses LCM, and why (measured with lcm 1.5.3, see ``benchmarks/bus.py``):

- One LCM subscription per exact channel, plus one shared ``.*`` only while a regex subscription
  exists. liblcm caches channel -> handlers, so 1,200 subscriptions cost the same per message as one,
  and a datagram nobody in this process listens to -- above all the process's own publications,
  which multicast loops back -- is dropped in C without waking Python.
- Each LCM subscription's queue is raised (the library default of 30 messages silently drops bursts).
- No thread of its own: the :class:`~antalate_lcm.core.executor.Executor` (the process's one event loop)
  waits on every instance's ``fileno()`` and calls ``handle`` when it is readable, so handlers run
  on the loop thread, where the nodes live, with no queue between (rclpy's wait set). A bus given
  no executor (:meth:`Buses.attach`) starts a private one on its first subscription.
- LCM subscriptions are added from the subscribing thread (liblcm guards its handler table) but
  removed only on the loop thread between two ``handle`` calls: unsubscribing from inside a
  handler can crash lcm 1.5.x.
- An instance's descriptor is watched from its first subscription, so a publish-only bus never
  reads its own traffic.
- udpm:// is read on the loop's own thread from a socket of our own (:mod:`antalate_lcm.transports.udpm`,
  liblcm's wire format in :mod:`antalate_lcm.transports.datagram`): one thread wake-up per message instead
  of liblcm's two (its receive thread, then its notify pipe), and a datagram nobody here wants (a
  process's own publications loop back) costs less dropped here than in liblcm's thread: 1,000
  agents in a process read 40,000 datagrams a second to keep a few, and liblcm's thread took a
  quarter of a core doing it (``benchmarks/agents.py``). ``own_udpm_reader=False`` (or
  ``ANTALATE_UDPM_READER=liblcm``) leaves udpm:// to liblcm.
- memq:// (an agent's in-process bus) does not go through liblcm's queue: a message for a channel
  someone here subscribes to is queued on the loop directly (no copy, no notify-pipe write per
  message), in publish order and never inside the publisher's call, as liblcm's memq would.
- Under load, a readable descriptor is drained within a time budget (not one batch per turn of
  the loop): a loop behind on a thousand agents' timers would otherwise starve its inputs.
"""

from __future__ import annotations

import logging
import os
import re
import threading
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.bus_connection import BusConnection, Handler, Subscription
from antalate_lcm.core.executor import Executor
from antalate_lcm.wire.topics import Message

log = logging.getLogger("antalate.bus")

#: ``liblcm`` here makes every `Buses` leave udpm:// to liblcm's receive thread.
UDPM_READER_ENV = "ANTALATE_UDPM_READER"

#: Messages LCM may queue for us before dropping (the library default of 30 drops bursts).
DEFAULT_QUEUE_CAPACITY = 10_000


class Buses:
    """Named LCM buses of a process (the paper's proxies). Thread-safe; share one per process.

    Handlers run on the thread of the executor the bus is attached to (:meth:`attach`; a
    :class:`~antalate_lcm.core.node.Context` attaches its own), where the nodes' callbacks run, so node
    code never needs locks. An unattached bus reads on a private executor thread of its own.
    """

    def __init__(
        self,
        urls: Mapping[str, str],
        *,
        queue_capacity: int = DEFAULT_QUEUE_CAPACITY,
        own_udpm_reader: bool | None = None,
    ) -> None:
        self.urls = dict(urls)
        #: Read udpm:// buses from a socket on the loop thread (module docstring); False leaves it to
        #: liblcm. None: yes, unless the environment says ``ANTALATE_UDPM_READER=liblcm`` (a way back
        #: for a network where the own reader misbehaves, and the baseline of benchmarks/tui.py).
        if own_udpm_reader is None:
            own_udpm_reader = os.environ.get(UDPM_READER_ENV, "own") != "liblcm"
        self.own_udpm_reader = own_udpm_reader
        self._queue_capacity = queue_capacity
        self._connections: dict[str, BusConnection] = {}
        self._by_name: dict[str, BusConnection] = {}
        self._lock = threading.Lock()
        self._decode_log = RateLimitedLog(log)
        self._publish_log = RateLimitedLog(log, period=10.0)
        self.publish_errors = 0
        self._closed = False
        self._executor: Executor | None = None
        self._own_executor = False

    def attach(self, executor: Executor) -> None:
        """Deliver on ``executor``'s loop; before the first subscription (handlers must not move)."""
        with self._lock:
            if self._executor is executor:
                return
            if self._executor is not None:
                raise RuntimeError("this bus already delivers on another executor")
            self._executor = executor

    @property
    def executor(self) -> Executor:
        """The loop that reads this bus (a private one, started now, if none was attached)."""
        with self._lock:
            if self._executor is None:
                self._executor = Executor(name="lcm-dispatch")
                self._own_executor = True
                self._executor.start()
            return self._executor

    def _connection(self, bus: str) -> BusConnection:
        conn = self._by_name.get(bus)
        if conn is not None:
            return conn
        try:
            url = self.urls[bus]
        except KeyError:
            raise KeyError(f"unknown bus {bus!r}; declared: {', '.join(self.urls)}") from None
        with self._lock:
            if self._closed:
                raise RuntimeError("bus is closed")
            conn = self._connections.get(url)
            if conn is None:
                conn = self._connections[url] = BusConnection(
                    url, self._queue_capacity, self._decode_log, lambda: self.executor, self.own_udpm_reader
                )
            self._by_name[bus] = conn
            return conn

    def open(self) -> None:
        """Open every declared bus now, so a missing multicast route is reported before nodes start."""
        for name in self.urls:
            self._connection(name)

    def publish(self, bus: str, channel: str, msg: Any) -> bool:
        """Encode and send; a send error (link down) is logged at a limited rate and returns False."""
        # A node sends bytes, already encoded (and signed): no isinstance on its path.
        data = msg if type(msg) is bytes else bytes(msg) if isinstance(msg, bytearray) else msg.encode()
        try:
            self._connection(bus).publish(channel, data)
        except OSError as exc:
            return self.publish_failed(bus, channel, exc)
        return True

    def sender(self, bus: str) -> Callable[[str, bytes], None]:
        """The send function of ``bus`` for encoded bytes, looked up once (a node's publisher keeps
        it: 20 messages a second per simulated agent, a lookup and two calls less each). It raises
        what ``publish`` would log: the caller reports an OSError through :meth:`publish_failed`."""
        return self._connection(bus).publish

    def publish_failed(self, bus: str, channel: str, exc: OSError) -> bool:
        """Count and log (rate-limited) a send that failed with ``exc``; False, what publish returns."""
        self.publish_errors += 1
        self._publish_log.log((bus, channel), logging.WARNING, "cannot send on %s %s: %s", bus, channel, exc)
        return False

    def subscribe(
        self,
        bus: str,
        channel: str,
        msg_type: type[Message] | None,
        handler: Handler,
        *,
        regex: bool = False,
        on_message: Callable[[Any], None] | None = None,
    ) -> Subscription:
        """Deliver every ``channel`` message, decoded as ``msg_type`` (raw bytes if None), to ``handler``.

        With ``regex=True`` the channel is a regular expression that must match the whole name.
        ``on_message`` (an exact channel only): called with the message alone instead of ``handler``.
        """
        if regex and on_message is not None:
            raise ValueError("on_message is for an exact channel (a pattern's handler needs the channel)")
        sub = Subscription(bus, channel, msg_type, handler, re.compile(channel) if regex else None)
        sub.on_message = on_message
        self._connection(bus).add(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        """Stop delivery; safe from inside a handler (the current delivery completes, no further one)."""
        sub.active = False
        conn = self._by_name.get(sub.bus)
        if conn is not None:
            conn.remove(sub)

    def decode_errors(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for conn in list(self._connections.values()):
            for channel, n in conn.decode_errors.items():
                out[channel] = out.get(channel, 0) + n
        return out

    def damaged_datagrams(self) -> int:
        """Datagrams this process's own udpm sockets dropped as not LCM or damaged."""
        return sum(conn.damaged for conn in list(self._connections.values()))

    def close(self) -> None:
        """Stop reading, release the sockets (and stop a private executor). Idempotent."""
        with self._lock:
            self._closed = True
            conns, self._connections, self._by_name = list(self._connections.values()), {}, {}
        for conn in conns:
            conn.close()
        if self._own_executor and self._executor is not None:
            self._executor.stop()

    def __enter__(self) -> Buses:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["DEFAULT_QUEUE_CAPACITY", "UDPM_READER_ENV", "Buses", "Handler", "Subscription"]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
