"""The ``zenoh://`` transport: antalate's LCM-encoded messages over Zenoh, past the first router.

:class:`Zenoh` checks its URLs (:mod:`.config`) and opens a :class:`ZenohLCM`. That offers the small part of ``lcm.LCM`` the bus uses -- ``publish``, ``subscribe`` (a channel regex
matched whole, as liblcm does) with ``set_queue_capacity``, ``unsubscribe``, ``handle``,
``handle_timeout`` and ``fileno`` -- so :class:`antalate_lcm.core.bus.Buses` drives it exactly like an LCM
instance, and so would an event loop waiting on ``fileno()``.

Why it is built this way:

- A sample carries exactly the bytes LCM would send (fingerprint and ``header.mac`` included), so
  signing and the replay guard work the same on both transports and across a bridge.
- One Zenoh key per channel, ``PREFIX/CHANNEL`` (channel characters Zenoh reserves are escaped), so
  Zenoh routes exact subscriptions itself; a regex subscription listens on ``PREFIX/**`` and filters.
- Zenoh calls back on its own threads; samples go to one FIFO and are handled by whoever calls
  ``handle`` (the bus's dispatcher thread), like LCM's. A socketpair is readable exactly while the
  FIFO holds a sample, so ``select`` on ``fileno()`` works.
- Each subscription queues at most its capacity (dropped beyond, as LCM does), so a slow handler
  cannot grow memory without bound on a fast link.
- A copy a bridge forwarded (attachment ``antalate-bridge:...``) is delivered once per subscription
  even when two bridges forward the same message: identical bytes on one channel within
  :data:`DEDUP_WINDOW` are one message (every antalate message has its own ``header.seq``/utime).
- Whatever a sender does, the state kept for it is bounded (issue 29: 10,000 new channel names once
  cost a bridge 29 MiB it never gave back). A declared publisher (a put costs 0.6 µs instead of ~6 µs)
  is kept only for a channel published at least :data:`HOT_AFTER` times, at most
  :data:`MAX_PUBLISHERS` of them (least recently used undeclared first), declared at most
  :data:`DECLARE_RATE` a second: a declaration costs ~450 µs and ~3 KB that Zenoh keeps after the
  undeclaration. Every other channel goes by ``session.put``, which keeps nothing. The duplicate
  memory holds at most :data:`MAX_SEEN` entries per subscription.
- ``max_message_size`` (the bridge sets it from its size limits) makes Zenoh itself drop a larger
  incoming message before reassembling it; the link stays up.
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import logging
import re
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from antalate_lcm.base.errors import BusUnavailable
from antalate_lcm.base.ratelimit import RateLimitedLog, TokenBucket
from antalate_lcm.transports.base import Connection, LcmUrl, Transport
from antalate_lcm.transports.zenoh.config import OPTIONS, ZENOH_NOT_LCM, check_url, zenoh_config
from antalate_lcm.transports.zenoh.groups import GroupProof, _Group
from antalate_lcm.transports.zenoh.keys import channel_key, key_channel, literal_channel

log = logging.getLogger("antalate.zenoh")

LcmHandler = Callable[..., None]

#: Attachment prefix of a sample a bridge forwarded (followed by the bridge's id).
BRIDGE_MARK = b"antalate-bridge:"
#: How long identical forwarded bytes on one channel count as the same message (s).
DEDUP_WINDOW = 2.0
#: LCM's default queue capacity per subscription (the bus raises it).
DEFAULT_CAPACITY = 30
#: Publications of a channel before it gets a declared publisher of its own.
HOT_AFTER = 3
#: Declared publishers kept at most (the least recently used is undeclared first).
MAX_PUBLISHERS = 256
#: Publisher declarations per second at most (and at once): the rest go by ``session.put``.
DECLARE_RATE = 20.0
DECLARE_BURST = 64.0
#: Channels whose publications are counted towards :data:`HOT_AFTER` (least recent forgotten first).
MAX_COUNTED = 4096
#: Forwarded messages each subscription remembers at most against duplicates (oldest forgotten first).
MAX_SEEN = 65_536


class Zenoh(Transport):
    """antalate's own: one Zenoh key ``PREFIX/CHANNEL`` per channel, through routers (docs/wan.md)."""

    scheme = "zenoh"
    options = OPTIONS
    not_lcm = ZENOH_NOT_LCM

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        return check_url(u)

    def open(self, *, max_message_size: int | None = None) -> Connection:
        return ZenohLCM(self.url.url, max_message_size=max_message_size)

    def for_slot(self, slot: int, step: int) -> str:
        """Runs on one Zenoh network hear each other whatever their ports: never apart."""
        raise ValueError(
            "parallel runs on one zenoh network would hear each other; use --jobs 1, or memq:// / udpm:// buses"
        )


@dataclass(eq=False)
class ZenohSubscription:
    """What :meth:`ZenohLCM.subscribe` returns (``set_queue_capacity`` as on an LCM subscription)."""

    regex: str
    handler: LcmHandler
    channel: str | None
    pattern: re.Pattern[str] | None
    capacity: int = DEFAULT_CAPACITY
    pending: int = 0
    dropped: int = 0
    active: bool = True
    remote_only: bool = False
    #: Call the handler with a third argument: the sample's attachment (bytes or None).
    attachments: bool = False
    zsub: Any = None
    seen: collections.OrderedDict[tuple[str, bytes], float] = field(default_factory=collections.OrderedDict)

    def set_queue_capacity(self, capacity: int) -> None:
        self.capacity = max(1, int(capacity))


class ZenohLCM:
    """A Zenoh session that looks like an ``lcm.LCM`` instance to the bus."""

    def __init__(self, url: str, *, max_message_size: int | None = None) -> None:
        try:
            u = Zenoh.parse(url)
        except ValueError as exc:
            raise BusUnavailable(url, f"expected {exc}") from None
        self.url = url
        self.prefix = u.network
        self._express = u.options.get("express", "0") == "1"
        try:
            import zenoh
        except ImportError:
            raise BusUnavailable(
                url, "the Zenoh library is not installed: pip install 'antalate[zenoh]'"
            ) from None
        self._zenoh = zenoh
        try:
            self._config = zenoh_config(u, max_message_size=max_message_size)
        except ValueError as exc:  # a TLS or credentials file that is not there
            raise BusUnavailable(url, str(exc)) from None
        self._session: Any = None
        self._subs: list[ZenohSubscription] = []
        self._groups: list[_Group] = []
        self._publishers: collections.OrderedDict[str, Any] = collections.OrderedDict()
        self._counts: collections.OrderedDict[str, int] = collections.OrderedDict()
        self._declarations = TokenBucket(DECLARE_RATE, DECLARE_BURST)
        self._pub_lock = threading.Lock()  # the publisher cache (publish may be called from any thread)
        self._queue: collections.deque[tuple[ZenohSubscription, str, bytes, bytes | None]] = (
            collections.deque()
        )
        self._lock = threading.Lock()  # the FIFO (taken on Zenoh's threads)
        self._subs_lock = threading.Lock()  # the session and the subscription list (never on Zenoh's threads)
        self._rsock, self._wsock = socket.socketpair()
        self._rsock.setblocking(False)
        self._wsock.setblocking(False)
        self._closed = False
        self._opened = threading.Event()
        #: Samples dropped because a subscription's queue was full.
        self.dropped = 0
        #: Liveliness tokens ignored because they were not signed with the group's key.
        self.ignored_tokens = 0
        self._log = RateLimitedLog(log, period=10.0)
        self._refresher: threading.Thread | None = None
        try:
            self._open()
        except zenoh.ZError as exc:
            # A client whose router is not reachable yet (vehicle booted before its LTE link): the
            # node starts anyway, publishing fails (counted by the bus) until the router answers.
            if "Unable to connect" not in str(exc):
                raise BusUnavailable(url, f"Zenoh could not open a session ({exc})") from None
            log.warning("%s: the Zenoh router is not reachable yet (%s); retrying every second", url, exc)
            threading.Thread(target=self._open_later, name=f"zenoh-open {url}", daemon=True).start()

    def _open(self) -> None:
        session = self._zenoh.open(self._config)
        with self._subs_lock:
            if self._closed:
                session.close()
                return
            self._session = session
            for sub in self._subs:
                if sub.active and sub.zsub is None:
                    self._declare(sub)
            for group in self._groups:
                self._declare_group(group)
        self._opened.set()

    def _open_later(self) -> None:
        while not self._closed:
            time.sleep(1.0)
            try:
                self._open()
            except self._zenoh.ZError:
                continue
            log.info("%s: connected to the Zenoh router", self.url)
            return

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def connected(self) -> bool:
        """Whether the session is open (a client reached its router at least once)."""
        return self._opened.is_set()

    # ------------------------------------------------------------------ lcm.LCM's interface
    def publish(self, channel: str, data: bytes, attachment: bytes | None = None) -> None:
        """Send ``data`` on ``channel``; raises OSError when the session is closed (like a dead socket)."""
        session = self._session
        if session is None:
            if self._closed:
                raise OSError(f"Zenoh session {self.url} is closed")
            raise OSError(f"Zenoh session {self.url}: the router has not been reached yet")
        try:
            publisher = self._publisher(session, channel)
            if publisher is not None:
                publisher.put(data, attachment=attachment)
            else:
                session.put(
                    channel_key(self.prefix, channel), data, express=self._express, attachment=attachment
                )
        except self._zenoh.ZError as exc:
            raise OSError(f"Zenoh session {self.url}: {exc}") from None

    def _publisher(self, session: Any, channel: str) -> Any:
        """The channel's declared publisher, declared now if it has become hot; None: use session.put."""
        with self._pub_lock:
            publisher = self._publishers.get(channel)
            if publisher is not None:
                self._publishers.move_to_end(channel)
                return publisher
            counts = self._counts
            n = counts.pop(channel, 0) + 1
            if n < HOT_AFTER or self._declarations.take(None, time.monotonic()) > 0:
                counts[channel] = n
                if len(counts) > MAX_COUNTED:
                    counts.popitem(last=False)
                return None
            if len(self._publishers) >= MAX_PUBLISHERS:
                _, old = self._publishers.popitem(last=False)
                with contextlib.suppress(self._zenoh.ZError):
                    old.undeclare()
            publisher = session.declare_publisher(channel_key(self.prefix, channel), express=self._express)
            self._publishers[channel] = publisher
            return publisher

    def subscribe(
        self, channel_regex: str, handler: LcmHandler, *, remote_only: bool = False, attachments: bool = False
    ) -> ZenohSubscription:
        """Deliver every message whose channel the regex matches whole; ``remote_only`` skips this
        session's own publications (a bridge must not hear itself); ``attachments`` passes each
        sample's attachment as a third argument (a bridge reads where a copy came from)."""
        channel = literal_channel(channel_regex)
        pattern = None if channel is not None else re.compile(channel_regex)
        sub = ZenohSubscription(
            channel_regex, handler, channel, pattern, remote_only=remote_only, attachments=attachments
        )
        with self._subs_lock:
            self._subs = [s for s in self._subs if s.active] + [sub]
            if self._session is not None:
                self._declare(sub)
        return sub

    def join_group(
        self,
        group: str,
        member: str,
        on_change: Callable[[frozenset[str]], None],
        proof: GroupProof | None = None,
    ) -> None:
        """Be ``member`` of ``group`` (a Zenoh liveliness token) and hear who else is, now and as it
        changes: ``on_change(members)``, this member always included. A member whose session dies
        leaves the group within the link lease. ``group`` and ``member``: key chunks (no ``/`` or ``.``).

        With a ``proof`` (the swarm key) only tokens signed with it count, re-declared every
        ``proof.refresh`` s; any other token is logged (rate-limited) and ignored (issue 29: an
        outsider's token once took the election over)."""
        g = _Group(f"{self.prefix}-groups/{group}", group, member, on_change, proof)
        with self._subs_lock:
            self._groups.append(g)
            if self._session is not None:
                self._declare_group(g)
        if proof is not None and self._refresher is None:
            self._refresher = threading.Thread(
                target=self._refresh_groups,
                args=(proof.refresh,),
                name=f"zenoh-groups {self.url}",
                daemon=True,
            )
            self._refresher.start()

    def _token_name(self, g: _Group) -> str:
        return g.member if g.proof is None else g.proof.token(g.group, g.member, time.time())

    def _declare_group(self, g: _Group) -> None:
        liveliness = self._session.liveliness()
        g.token = liveliness.declare_token(f"{g.key}/{self._token_name(g)}")

        def changed(sample: Any) -> None:
            name = str(sample.key_expr).rsplit("/", 1)[-1]
            alive = sample.kind != self._zenoh.SampleKind.DELETE
            problem = g.seen(name, alive, time.time())
            if problem is not None:
                self.ignored_tokens += 1
                self._log.log(
                    (g.key, "token"),
                    logging.WARNING,
                    "%s: ignored a liveliness token in %s that is not from a bridge of this swarm (%s): %s",
                    self.url,
                    g.key,
                    problem,
                    name[:80],
                )
            g.report()

        g.sub = liveliness.declare_subscriber(f"{g.key}/*", changed, history=True)

    def _refresh_groups(self, period: float) -> None:
        """Re-declare each signed token (the new one first: the member never leaves) and forget
        members whose newest token went stale."""
        while not self._closed:
            time.sleep(period)
            with self._subs_lock:
                if self._session is None:
                    continue
                for g in self._groups:
                    if g.proof is None:
                        continue
                    old = g.token
                    with contextlib.suppress(self._zenoh.ZError):
                        g.token = self._session.liveliness().declare_token(f"{g.key}/{self._token_name(g)}")
                        if old is not None:
                            old.undeclare()
                    g.expire(time.time())
                    g.report()

    def _declare(self, sub: ZenohSubscription) -> None:
        key = channel_key(self.prefix, sub.channel) if sub.channel is not None else f"{self.prefix}/**"
        origin = self._zenoh.Locality.REMOTE if sub.remote_only else None
        sub.zsub = self._session.declare_subscriber(
            key, lambda sample: self._on_sample(sub, sample), allowed_origin=origin
        )

    def unsubscribe(self, sub: ZenohSubscription) -> None:
        sub.active = False
        if sub.zsub is not None:
            zsub, sub.zsub = sub.zsub, None
            with contextlib.suppress(self._zenoh.ZError):  # the session is already closed
                zsub.undeclare()

    def fileno(self) -> int:
        """Readable while a received message waits for :meth:`handle`."""
        return self._rsock.fileno()

    def handle(self) -> int:
        """Handle one message, waiting as long as it takes."""
        while not self.handle_timeout(1000):
            if self._closed:
                raise OSError(f"Zenoh session {self.url} is closed")
        return 0

    def handle_timeout(self, timeout_ms: int) -> int:
        """Handle one message if one arrives within ``timeout_ms``: 1 if one was handled, else 0."""
        item = self._pop()
        if item is None:
            if self._closed:
                raise OSError(f"Zenoh session {self.url} is closed")
            if timeout_ms <= 0:
                return 0  # a sample arriving now makes fileno() readable again: no need to look
            readable, _, _ = select.select([self._rsock], [], [], max(0, timeout_ms) / 1000)
            if not readable:
                return 0
            item = self._pop()
            if item is None:
                return 0
        sub, channel, data, attachment = item
        if sub.active:
            if sub.attachments:
                sub.handler(channel, data, attachment)
            else:
                sub.handler(channel, data)
        return 1

    def close(self) -> None:
        """Close the session (every subscription with it). Idempotent."""
        if self._closed:
            return
        with self._subs_lock:
            self._closed = True
            session, self._session = self._session, None
        try:
            if session is not None:
                session.close()
        except Exception:  # noqa: BLE001 - closing must not fail a shutdown
            log.debug("closing %s", self.url, exc_info=True)
        with self._pub_lock:
            self._publishers.clear()
            self._counts.clear()
        self._rsock.close()
        self._wsock.close()

    # ------------------------------------------------------------------ Zenoh's threads
    def _on_sample(self, sub: ZenohSubscription, sample: Any) -> None:
        if not sub.active:
            return
        channel = sub.channel
        if channel is None:
            channel = key_channel(self.prefix, str(sample.key_expr))
            if channel is None or sub.pattern is None or not sub.pattern.fullmatch(channel):
                return
        data = sample.payload.to_bytes()
        zatt = sample.attachment
        attachment = zatt.to_bytes() if zatt is not None else None
        forwarded = attachment is not None and attachment.startswith(BRIDGE_MARK)
        with self._lock:
            if forwarded and _duplicate(sub, channel, data):
                return
            if sub.pending >= sub.capacity:
                sub.dropped += 1
                self.dropped += 1
                return
            sub.pending += 1
            was_empty = not self._queue
            self._queue.append((sub, channel, data, attachment))
            if was_empty and not self._closed:
                with contextlib.suppress(OSError):  # closing, or the byte is already there
                    self._wsock.send(b"\0")

    def _pop(self) -> tuple[ZenohSubscription, str, bytes, bytes | None] | None:
        with self._lock:
            if not self._queue:
                return None
            item = self._queue.popleft()
            item[0].pending -= 1
            if not self._queue:
                try:
                    while self._rsock.recv(4096):
                        pass
                except OSError:
                    pass  # drained (BlockingIOError) or closed
            return item


def _duplicate(sub: ZenohSubscription, channel: str, data: bytes) -> bool:
    """Whether this subscription already had these forwarded bytes on this channel lately."""
    now = time.monotonic()
    key = (channel, hashlib.blake2b(data, digest_size=16).digest())
    seen = sub.seen
    while seen:  # oldest first: forget what left the window (O(1) per message)
        oldest, t = next(iter(seen.items()))
        if now - t <= DEDUP_WINDOW:
            break
        del seen[oldest]
    last = seen.pop(key, None)
    seen[key] = now
    if len(seen) > MAX_SEEN:
        seen.popitem(last=False)
    return last is not None


__all__ = [
    "BRIDGE_MARK",
    "DEDUP_WINDOW",
    "ZenohLCM",
    "ZenohSubscription",
    "channel_key",
    "key_channel",
    "literal_channel",
    "Zenoh",
]
