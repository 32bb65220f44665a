"""One bus URL of a :class:`~antalate_lcm.core.bus.Buses`: its transport's connection, the subscribers of
each channel, and how the process's event loop reads it (the why of every choice is in
:mod:`antalate_lcm.core.bus`'s docstring).

Kept apart from the ``Buses`` (the names, the executor, the public calls) because this is the hot path:
what runs per datagram (``_on_exact``, ``_on_pattern``, ``_deliver``), per publish, and the own udpm
socket's kernel filter.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.executor import Executor
from antalate_lcm.transports import Transport, transport_for
from antalate_lcm.transports.udpm import Udpm, UdpmReceiver, UdpmSender
from antalate_lcm.wire.fastcodec import decoder
from antalate_lcm.wire.topics import Message

log = logging.getLogger("antalate.bus")

Handler = Callable[[str, Any], None]

#: Marks a type that failed to decode this datagram (so later subscribers skip it silently).
_UNDECODABLE = object()

#: Messages handled per readable event before the loop looks at its timers and other descriptors.
_BATCH = 64
#: s a readable descriptor may keep the loop beyond the first batch while messages still wait.
_DRAIN_BUDGET = 0.02


@dataclass(eq=False, slots=True)
class Subscription:
    """A handle returned by :meth:`Buses.subscribe`; pass it to :meth:`Buses.unsubscribe`.

    Slotted: every delivery reads its ``active`` and ``handler`` (5 per agent, a thousand agents)."""

    bus: str
    channel: str
    msg_type: type[Message] | None
    handler: Handler
    regex: re.Pattern[str] | None = None
    active: bool = field(default=True)
    #: Called with the message alone in place of ``handler`` (exact channels only): a node's handler
    #: that needs no channel and no admission, with no closure to call in between (`Node.subscribe`).
    on_message: Callable[[Any], None] | None = field(default=None, repr=False)
    #: ``msg_type``'s decoder (antalate_lcm.wire.fastcodec: lcm-gen's fields, a third of its time).
    decode: Callable[[bytes], Any] | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.msg_type is not None:
            self.decode = decoder(self.msg_type)


#: Characters with a meaning in LCM's channel regular expressions.
_REGEX_SPECIAL = re.compile(r"([.^$*+?()\[\]{}|\\])")


def lcm_literal(channel: str) -> str:
    """An LCM channel regex matching exactly ``channel``."""
    return _REGEX_SPECIAL.sub(r"\\\1", channel)


class _Route:
    """The subscribers of one exact channel and the LCM subscription that feeds them."""

    __slots__ = ("subs", "decode", "lcm_sub", "retired")

    def __init__(self) -> None:
        self.subs: tuple[Subscription, ...] = ()
        #: The subscribers' one decoder (one subscriber, or several of one type), else None.
        self.decode: Callable[[bytes], Any] | None = None
        self.lcm_sub: Any = None
        self.retired = False

    def set_subs(self, subs: tuple[Subscription, ...]) -> None:
        """Under the connection's lock: the subscribers, and their decoder if they share one."""
        one_type = len({sub.msg_type for sub in subs}) == 1
        self.decode = subs[0].decode if one_type else None
        self.subs = subs


class BusConnection:
    """One bus URL opened (its transport's connection), its channels' subscribers, read by the event
    loop while it has subscriptions; a :class:`~antalate_lcm.core.bus.Buses` keeps one per URL."""

    def __init__(
        self,
        url: str,
        queue_capacity: int,
        decode_log: RateLimitedLog,
        executor: Callable[[], Executor],
        own_reader: bool = False,
    ) -> None:
        self.url = url
        transport: Transport = transport_for(url)
        self._lcm: Any = transport.open()
        #: The udpm transport, when this connection reads it from our own socket on the loop thread.
        self._udpm = transport if own_reader and isinstance(transport, Udpm) else None
        self._own_reader = self._udpm is not None
        #: The receive socket (None until the first subscription).
        self._receiver: UdpmReceiver | None = None
        #: Sends the short messages when the connection reads its own socket (None until the first publish).
        self._sender: UdpmSender | None = None
        #: The receiver drops the sender's own datagrams in the kernel (see _own_filter).
        self._ignoring = False
        #: Once a subscription of this connection could want the process's own messages (a pattern, or a
        #: channel it publishes), they are heard again, for good.
        self._hear_own = False
        #: The last ``/``-part of every channel ever subscribed exactly (what the filter lets through).
        self._topics: frozenset[str] = frozenset()
        self._damaged_seen = 0
        self._capacity = queue_capacity
        # Routing tables are replaced, never mutated, so the loop reads them without a lock.
        self._routes: dict[str, _Route] = {}
        self._patterns: tuple[Subscription, ...] = ()
        self._matched: dict[str, tuple[Subscription, ...]] = {}
        self._matched_for: tuple[Subscription, ...] = ()
        self._star: Any = None
        self._retire: list[Any] = []
        self._lock = threading.Lock()
        self._executor = executor
        self._watched: tuple[Executor, int] | None = None
        #: A readable descriptor means handle() returns at once (liblcm's udpm and memq pipes).
        self._ready_means_message = transport.ready_means_message
        #: memq:// is private to this instance: a datagram nobody here subscribes to goes nowhere.
        #: (An agent's in-process bus carries TELEMETRY at 10 Hz that no node of the process reads.)
        self._private = transport.in_process
        #: memq:// messages published on the loop thread, waiting for their one delivering handle.
        self._pending: list[tuple[_Route | None, str, bytes, bool]] = []
        self._decode_log = decode_log
        self.decode_errors: dict[str, int] = {}
        #: Datagrams delivered to at least one subscriber.
        self.received = 0

    def add(self, sub: Subscription) -> None:
        lc = self._lcm
        assert lc is not None, "bus is closed"
        with self._lock:
            own = self._own_reader
            if own and self._receiver is None:
                # First, so a socket that cannot open leaves no subscription behind.
                self._receiver = self._open_receiver()
            if sub.regex is None:
                route = self._routes.get(sub.channel)
                if route is None:
                    route = _Route()
                    if not own:
                        route.lcm_sub = lc.subscribe(lcm_literal(sub.channel), partial(self._on_exact, route))
                        route.lcm_sub.set_queue_capacity(self._capacity)
                    self._routes = {**self._routes, sub.channel: route}
                    topic = sub.channel.rsplit("/", 1)[-1]
                    if topic not in self._topics:
                        self._topics = self._topics | {topic}
                route.set_subs((*route.subs, sub))
            else:
                self._patterns = (*self._patterns, sub)
                if own:  # it may match anything, this process's own datagrams included
                    self._hear_own = True
                    self._own_filter()
                if self._star is None and not own:
                    self._star = lc.subscribe(".*", self._on_pattern)
                    self._star.set_queue_capacity(self._capacity)
            watch = self._watched is None
            if watch:
                ex = self._executor()
                if self._receiver is not None:
                    fd, on_readable = self._receiver.fileno(), self._on_datagrams
                else:
                    fd, on_readable = lc.fileno(), self._on_readable  # liblcm starts reading here
                self._watched = (ex, fd)
            if own:
                self._own_filter()
        if watch:
            # The own socket's kernel buffer is its only queue: read it between long runs of timers too.
            ex.add_reader(fd, on_readable, urgent=own)

    def _own_filter(self) -> None:
        """Under the lock: have the kernel drop, on the receive socket, what no subscription of the
        connection can want: the process's own datagrams (while no pattern, and no channel it both
        publishes and subscribes: then :meth:`publish` turns that off) and the short messages of
        channels whose last ``/``-part no exact subscription has (while no pattern). A thousand
        simulated agents read their own 20,000 datagrams a second and every other agent process's
        only to drop them by channel."""
        receiver = self._receiver
        if receiver is None:
            return
        own: tuple[str, int] | None = None
        topics: frozenset[str] | None = None
        if not self._patterns:
            if self._sender is not None and not self._hear_own:
                own = self._sender.address
            if self._topics:
                topics = self._topics
        receiver.narrow(own, topics)
        self._ignoring = receiver.drops_own

    def _hear_own_messages(self) -> None:
        """Under the lock: the receive socket hears this process's own datagrams again, for good."""
        self._hear_own = True
        self._own_filter()

    def _open_receiver(self) -> UdpmReceiver:
        assert self._udpm is not None
        return self._udpm.receiver()

    def remove(self, sub: Subscription) -> None:
        sub.active = False
        with self._lock:
            if sub.regex is None:
                route = self._routes.get(sub.channel)
                if route is None:
                    return
                route.set_subs(tuple(s for s in route.subs if s is not sub))
                if not route.subs:
                    route.retired = True  # a late datagram must not reach a re-subscribed channel twice
                    if route.lcm_sub is not None:
                        self._retire.append(route.lcm_sub)
                    # A copy without it (C's dict copy: a thousand agents' nodes stopping one by
                    # one rebuilt the table in Python per subscription, seconds of the run's end).
                    routes = self._routes.copy()
                    del routes[sub.channel]
                    self._routes = routes
            else:
                self._patterns = tuple(s for s in self._patterns if s is not sub)
                if not self._patterns and self._star is not None:
                    self._retire.append(self._star)
                    self._star = None
            watched = self._watched
        if self._retire and watched is not None:
            watched[0].call_soon(self._flush_retired)

    def publish(self, channel: str, data: bytes) -> None:
        lc = self._lcm
        if lc is None:  # a sender (Bus.sender) kept past the bus's close: as Bus.publish then
            raise RuntimeError("bus is closed")
        if self._private:
            # memq:// reaches only this instance's subscribers, all read on one loop: the message
            # is queued on that loop directly (liblcm's memq would copy it, write its notify pipe
            # and wait for a handle() of its own: a system call per message, 10,000 a second for
            # 1,000 agents' state), in publish order, never run inside the publisher's call.
            watched = self._watched
            if watched is None:
                return  # no subscriber yet
            route = self._routes.get(channel)
            patterns = bool(self._patterns)
            if route is None and not patterns:
                return
            ex = watched[0]
            if not ex.on_loop():  # another thread: a loop handle of its own (thread-safe)
                if route is not None:
                    ex.call_soon(self._on_exact, route, channel, data)
                if patterns:
                    ex.call_soon(self._on_pattern, channel, data)
                return
            # On the loop: queued for one handle that delivers every message published until it
            # runs (a thousand agents' state in a tick is one handle, not a thousand).
            pending = self._pending
            if not pending:
                ex.call_soon(self._deliver_pending)
            pending.append((route, channel, data, patterns))
            return
        sender = self._sender
        if sender is None:
            if not self._own_reader:
                lc.publish(channel, data)
                return
            sender = self._open_sender()
        if self._ignoring and channel in self._routes:
            # A subscriber of this process wants what it sends on this channel.
            with self._lock:
                self._hear_own_messages()
        if not sender.publish(channel, data):
            lc.publish(channel, data)  # too large for one datagram: liblcm fragments it

    def _open_sender(self) -> UdpmSender:
        with self._lock:
            if self._sender is None:
                assert self._udpm is not None
                self._sender = self._udpm.sender()
                self._own_filter()
            return self._sender

    def _deliver_pending(self) -> None:
        """On the loop thread: the memq:// messages published on it since the last call, in order."""
        pending, self._pending = self._pending, []
        on_exact, on_pattern = self._on_exact, self._on_pattern
        for route, channel, data, patterns in pending:
            try:
                if route is not None:
                    on_exact(route, channel, data)
                if patterns:
                    on_pattern(channel, data, route is None or route.retired)
            except Exception:  # as the loop's own handles: logged, and the next message goes on
                log.exception("delivering %s on %s failed; the bus carries on", channel, self.url)

    def _on_readable(self) -> None:
        """On the loop thread: handle what is queued (a batch at most), then drop retired subscriptions."""
        lc = self._lcm
        if lc is None:
            return
        try:
            if self._ready_means_message:
                lc.handle()  # liblcm's pipe is readable exactly while a message waits: no block
            # handle_timeout(0) for the rest (and for other transports): a spurious wake-up must
            # never block the whole loop.
            for _ in range(_BATCH):
                if lc.handle_timeout(0) <= 0:
                    break
            else:  # more waiting: drain within a time budget before the loop turns to its timers
                # (a loop behind on a thousand agents' timers polls seldom; 64 messages a turn
                # then starved the inputs by seconds: MCs declared their HLC lost).
                end = time.monotonic() + _DRAIN_BUDGET
                while lc.handle_timeout(0) > 0 and time.monotonic() < end:
                    pass
        except OSError as exc:
            # A finished file:// log (replay) ends here; a socket error would repeat forever.
            log.info("LCM provider %s stopped delivering: %s", self.url, exc)
            self._unwatch()
        if self._retire:
            self._flush_retired()

    def _on_datagrams(self) -> None:
        """On the loop thread: the own udpm socket is readable; the same batch and budget as liblcm's."""
        receiver = self._receiver
        if receiver is None:
            return
        try:
            if receiver.drain(self._dispatch, _BATCH) == _BATCH:
                end = time.monotonic() + _DRAIN_BUDGET
                while receiver.drain(self._dispatch, _BATCH) == _BATCH and time.monotonic() < end:
                    pass
        except OSError as exc:  # never EAGAIN (drain stops there): a socket that cannot be read
            self._decode_log.log((self.url, "socket"), logging.WARNING, "reading %s: %s", self.url, exc)
        r = receiver.reassembler
        if r.dropped + r.evicted != self._damaged_seen:  # liblcm drops these silently; say so, rate-limited
            self._damaged_seen = r.dropped + r.evicted
            self._decode_log.log(
                (self.url, "damaged"),
                logging.WARNING,
                "dropped datagrams on %s that are not LCM or are damaged: %d so far, and %d partial "
                "messages whose fragments never all came",
                self.url,
                r.dropped,
                r.evicted,
            )

    def _dispatch(self, channel: str, data: bytes) -> None:
        """A datagram from the own socket, to the subscribers liblcm would have handed it to."""
        route = self._routes.get(channel)
        if route is not None:
            self._on_exact(route, channel, data)
        if self._patterns:
            self._on_pattern(channel, data, route is None or route.retired)

    @property
    def damaged(self) -> int:
        """Datagrams on the own udpm socket that were not LCM or were damaged (liblcm drops them too)."""
        return 0 if self._receiver is None else self._receiver.reassembler.dropped

    def _flush_retired(self) -> None:
        lc = self._lcm
        with self._lock:
            retire, self._retire = self._retire, []
        if lc is not None:
            for lcm_sub in retire:
                lc.unsubscribe(lcm_sub)

    def _unwatch(self) -> None:
        with self._lock:
            watched, self._watched = self._watched, None
        if watched is not None:
            watched[0].remove_reader(watched[1])

    def _on_exact(self, route: _Route, channel: str, data: bytes) -> None:
        if route.retired:
            return
        subs, decode = route.subs, route.decode
        if decode is None and len(subs) != 1:
            self._deliver(channel, data, subs)
            return
        # One subscriber (the common case), or several of one type (an agent's MC state to its HLC
        # and BMA): `_deliver`'s work without its per-datagram table. Several get the one message
        # (as from `_deliver`: a handler must not change what it is given).
        self.received += 1
        msg: Any = data
        if decode is not None:
            try:
                msg = decode(data)
            except Exception as exc:  # noqa: BLE001 - any garbage must not kill the node
                self._count_decode_error(channel, subs[0].msg_type, data, exc)  # type: ignore[arg-type]
                return
        for sub in subs:
            if sub.active:
                try:
                    sub.handler(channel, msg) if sub.on_message is None else sub.on_message(msg)
                except Exception:
                    log.exception("handler for %s on %s raised; the bus carries on", channel, self.url)

    def _on_pattern(self, channel: str, data: bytes, count: bool | None = None) -> None:
        # The matching subscribers of a channel, remembered until the patterns change: a console
        # watching 1,000 agents would otherwise run its regexes on every datagram.
        patterns = self._patterns
        if self._matched_for is not patterns:
            self._matched, self._matched_for = {}, patterns
        subs = self._matched.get(channel)
        if subs is None:
            subs = tuple(s for s in patterns if s.regex is not None and s.regex.fullmatch(channel))
            if len(self._matched) < 100_000:  # bounded: channel names come from the network
                self._matched[channel] = subs
        if not subs:
            return
        # A channel that also has an exact route is counted there: one datagram, one count
        # (``count``: the caller knows whether it has one).
        if count is None:
            count = channel not in self._routes
        sub = subs[0]
        if len(subs) == 1 and sub.msg_type is None and sub.active:
            # One raw subscriber (the console's 15,000 datagrams a second): no decode table.
            if count:
                self.received += 1
            try:
                sub.handler(channel, data)
            except Exception:
                log.exception("handler for %s on %s raised; the bus carries on", channel, self.url)
            return
        self._deliver(channel, data, subs, count=count)

    def _deliver(
        self, channel: str, data: bytes, subs: tuple[Subscription, ...], *, count: bool = True
    ) -> None:
        if count:
            self.received += 1
        # One decode per type per datagram, failures included: a bad datagram is one decode error
        # however many subscribers the channel has.
        decoded: dict[type, Any] = {}
        for sub in subs:
            if not sub.active:
                continue
            msg: Any = data
            msg_type = sub.msg_type
            if msg_type is not None:
                msg = decoded.get(msg_type)
                if msg is None:
                    try:
                        msg = decoded[msg_type] = decoder(msg_type)(data)
                    except Exception as exc:  # noqa: BLE001 - any garbage must not kill the node
                        decoded[msg_type] = _UNDECODABLE
                        if count:
                            self._count_decode_error(channel, msg_type, data, exc)
                        continue
                elif msg is _UNDECODABLE:
                    continue
            try:
                sub.handler(channel, msg) if sub.on_message is None else sub.on_message(msg)
            except Exception:
                log.exception("handler for %s on %s raised; the bus carries on", channel, self.url)

    def _count_decode_error(self, channel: str, msg_type: type[Message], data: bytes, exc: Exception) -> None:
        n = self.decode_errors.get(channel, 0) + 1
        self.decode_errors[channel] = n
        self._decode_log.log(
            (self.url, channel),
            logging.WARNING,
            "dropped a %d-byte datagram on %s that is not a valid %s (%s); %d so far on this channel",
            len(data),
            channel,
            msg_type.__name__,
            exc,
            n,
        )

    def close(self) -> None:
        self._unwatch()
        receiver, self._receiver = self._receiver, None
        if receiver is not None:
            receiver.close()
        sender, self._sender = self._sender, None
        if sender is not None:
            sender.close()
        # liblcm frees its sockets when the object is deallocated; drop our only reference.
        lc, self._lcm = self._lcm, None
        if hasattr(lc, "close"):
            lc.close()  # a Zenoh session is closed explicitly (its links and threads)


__all__ = ["BusConnection", "Handler", "Subscription", "lcm_literal"]
