"""The bus: named LCM instances with typed publish/subscribe and one dispatcher thread each.

Why one LCM subscription per instance (``.*``) and a Python dict for routing: LCM matches every
datagram against every subscription's regex in C, so 200 agents x 6 subscriptions in one process
would cost a regex scan per message; a dict lookup is O(1). It also sidesteps two lcm 1.5.x
pitfalls: the per-subscription queue (default 30 messages, silently dropping bursts) is raised once,
and unsubscribing never touches LCM from inside a handler, which can crash it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import lcm

from antalate_lcm._ratelimit import RateLimitedLog
from antalate_lcm.errors import MulticastUnavailable

log = logging.getLogger("antalate.bus")

Handler = Callable[[str, Any], None]

#: Messages LCM may queue for us before dropping (the library default of 30 drops bursts).
DEFAULT_QUEUE_CAPACITY = 10_000


@dataclass(eq=False)
class Subscription:
    """A handle returned by :meth:`Bus.subscribe`; pass it to :meth:`Bus.unsubscribe`."""

    bus: str
    channel: str
    msg_type: type | None
    handler: Handler
    regex: re.Pattern[str] | None = None
    active: bool = field(default=True)


@contextlib.contextmanager
def _captured_stderr() -> Iterator[list[str]]:
    """Swallow what liblcm prints on fd 2 while it opens sockets; our own error says it better."""
    lines: list[str] = []
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = os.dup(2)
        try:
            os.dup2(tmp.fileno(), 2)
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(tmp.read().decode(errors="replace").splitlines())


def open_lcm(url: str) -> lcm.LCM:
    """Create an LCM instance, turning 'Couldn't create LCM' into a message that says the fix."""
    try:
        with _captured_stderr() as noise:
            return lcm.LCM(url)
    except (RuntimeError, OSError):
        log.debug("liblcm said: %s", " | ".join(noise))
        if url.startswith("udpm://"):
            raise MulticastUnavailable(url) from None
        raise


class _Link:
    """One LCM instance and its dispatcher thread."""

    def __init__(self, url: str, queue_capacity: int, decode_log: RateLimitedLog) -> None:
        self.url = url
        self._lcm: lcm.LCM | None = open_lcm(url)
        self._exact: dict[str, tuple[Subscription, ...]] = {}
        self._patterns: tuple[Subscription, ...] = ()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._decode_log = decode_log
        self.decode_errors: dict[str, int] = {}
        self.handler_errors = 0
        self.received = 0
        sub = self._lcm.subscribe(".*", self._on_datagram)
        sub.set_queue_capacity(queue_capacity)
        self._thread = threading.Thread(target=self._run, name=f"lcm-dispatch {url}", daemon=True)
        self._thread.start()

    # -- routing tables are replaced, never mutated, so the dispatcher reads them without a lock
    def add(self, sub: Subscription) -> None:
        with self._lock:
            if sub.regex is None:
                self._exact = {**self._exact, sub.channel: (*self._exact.get(sub.channel, ()), sub)}
            else:
                self._patterns = (*self._patterns, sub)

    def remove(self, sub: Subscription) -> None:
        sub.active = False
        with self._lock:
            if sub.regex is None:
                rest = tuple(s for s in self._exact.get(sub.channel, ()) if s is not sub)
                exact = dict(self._exact)
                if rest:
                    exact[sub.channel] = rest
                else:
                    exact.pop(sub.channel, None)
                self._exact = exact
            else:
                self._patterns = tuple(s for s in self._patterns if s is not sub)

    def publish(self, channel: str, data: bytes) -> None:
        assert self._lcm is not None, "bus is closed"
        self._lcm.publish(channel, data)

    def _run(self) -> None:
        lc = self._lcm
        assert lc is not None
        while not self._stop.is_set():
            lc.handle_timeout(100)

    def _on_datagram(self, channel: str, data: bytes) -> None:
        self.received += 1
        subs = self._exact.get(channel, ())
        if self._patterns:
            subs = subs + tuple(s for s in self._patterns if s.regex is not None and s.regex.fullmatch(channel))
        decoded: dict[type, Any] = {}
        for sub in subs:
            if not sub.active:
                continue
            msg: Any = data
            if sub.msg_type is not None:
                if sub.msg_type in decoded:
                    msg = decoded[sub.msg_type]
                else:
                    try:
                        msg = decoded[sub.msg_type] = sub.msg_type.decode(data)
                    except Exception as exc:  # noqa: BLE001 - any garbage must not kill the node
                        self._count_decode_error(channel, sub.msg_type, data, exc)
                        continue
            try:
                sub.handler(channel, msg)
            except Exception:
                self.handler_errors += 1
                log.exception("handler for %s on %s raised; the bus carries on", channel, self.url)

    def _count_decode_error(self, channel: str, msg_type: type, data: bytes, exc: Exception) -> None:
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
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join()
        # liblcm frees its sockets when the object is deallocated; drop our only reference.
        self._lcm = None


class Bus:
    """Named LCM buses of a process (the paper's proxies). Thread-safe; share one per process.

    Handlers run on the bus's dispatcher thread; nodes hand them to their executor
    (:class:`antalate_lcm.node.Node` does this), so node code never needs locks.
    """

    def __init__(self, urls: Mapping[str, str], *, queue_capacity: int = DEFAULT_QUEUE_CAPACITY) -> None:
        self.urls = dict(urls)
        self._queue_capacity = queue_capacity
        self._links: dict[str, _Link] = {}
        self._lock = threading.Lock()
        self._decode_log = RateLimitedLog(log)
        self._publish_log = RateLimitedLog(log, period=10.0)
        self.publish_errors = 0
        self._closed = False

    def _link(self, bus: str) -> _Link:
        try:
            url = self.urls[bus]
        except KeyError:
            raise KeyError(f"unknown bus {bus!r}; declared: {', '.join(self.urls)}") from None
        with self._lock:
            if self._closed:
                raise RuntimeError("bus is closed")
            link = self._links.get(url)
            if link is None:
                link = self._links[url] = _Link(url, self._queue_capacity, self._decode_log)
            return link

    def open(self) -> None:
        """Open every declared bus now, so a missing multicast route is reported before nodes start."""
        for name in self.urls:
            self._link(name)

    def publish(self, bus: str, channel: str, msg: Any) -> bool:
        """Encode and send; a send error (link down) is logged at a limited rate and returns False."""
        data = msg if isinstance(msg, bytes | bytearray) else msg.encode()
        try:
            self._link(bus).publish(channel, data)
        except OSError as exc:
            self.publish_errors += 1
            self._publish_log.log((bus, channel), logging.WARNING, "cannot send on %s %s: %s", bus, channel, exc)
            return False
        return True

    def subscribe(
        self, bus: str, channel: str, msg_type: type | None, handler: Handler, *, regex: bool = False
    ) -> Subscription:
        """Deliver every ``channel`` message, decoded as ``msg_type`` (raw bytes if None), to ``handler``.

        With ``regex=True`` the channel is a regular expression that must match the whole name.
        """
        sub = Subscription(bus, channel, msg_type, handler, re.compile(channel) if regex else None)
        self._link(bus).add(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        """Stop delivery; safe from inside a handler (the current delivery completes, no further one)."""
        sub.active = False
        link = self._links.get(self.urls.get(sub.bus, ""))
        if link is not None:
            link.remove(sub)

    def decode_errors(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for link in list(self._links.values()):
            for channel, n in link.decode_errors.items():
                out[channel] = out.get(channel, 0) + n
        return out

    def close(self) -> None:
        """Stop every dispatcher thread and release the sockets. Idempotent."""
        with self._lock:
            self._closed = True
            links, self._links = list(self._links.values()), {}
        for link in links:
            link.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
