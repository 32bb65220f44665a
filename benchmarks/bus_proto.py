"""A prototype of a faster dispatch path for :class:`antalate_lcm.bus.Bus`, measured by ``benchmarks/bus.py --proto``.

Not used by antalate itself: it exists to show, with figures, what changing ``antalate_lcm/bus.py`` buys.
Same public API and semantics as ``Bus``; three changes:

1. **LCM filters channels in C.** One LCM subscription per exact channel (instead of one ``.*`` for
   everything), plus one shared ``.*`` only while a regex subscription exists. lcm 1.5 caches channel ->
   handlers, so 1,200 subscriptions cost the same per message as one (measured: 2.1 us either way), and a
   datagram nobody in this process subscribed to -- above all the process's *own* publications, which
   multicast loops back -- is dropped in C without waking Python.
2. **No receive side until the first subscription.** A publish-only link never starts a dispatcher
   thread, so it never reads (and never pays for) its own traffic.
3. **Fewer steps per message.** ``publish`` finds the link without the lock; a datagram for a single
   subscriber skips the decode cache and the pattern scan.

LCM subscriptions are added from the subscribing thread (liblcm guards its handler table with a mutex)
and removed only by the dispatcher thread between two ``handle`` calls, never inside a handler.
"""

from __future__ import annotations

import logging
import re
import threading
from functools import partial
from typing import Any

import lcm

from antalate_lcm.bus import DEFAULT_QUEUE_CAPACITY, Subscription, log, open_lcm
from antalate_lcm.bus import Bus as _BaseBus

#: Characters that mean something in LCM's regular expressions (POSIX extended and PCRE alike).
_REGEX_SPECIAL = re.compile(r"([.^$*+?()\[\]{}|\\])")


def lcm_literal(channel: str) -> str:
    return _REGEX_SPECIAL.sub(r"\\\1", channel)


class _Route:
    """The subscribers of one exact channel and the LCM subscription that feeds them."""

    __slots__ = ("subs", "lcm_sub", "retired")

    def __init__(self) -> None:
        self.subs: tuple[Subscription, ...] = ()
        self.lcm_sub: Any = None
        self.retired = False


class _ProtoLink:
    def __init__(self, url: str, queue_capacity: int, decode_log: Any) -> None:
        self.url = url
        self._lcm: lcm.LCM | None = open_lcm(url)
        self._capacity = queue_capacity
        self._routes: dict[str, _Route] = {}
        self._patterns: tuple[Subscription, ...] = ()
        self._star: Any = None
        self._retire: list[Any] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._decode_log = decode_log
        self.decode_errors: dict[str, int] = {}
        self.handler_errors = 0
        self.received = 0

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"lcm-dispatch {self.url}", daemon=True)
            self._thread.start()

    def add(self, sub: Subscription) -> None:
        assert self._lcm is not None, "bus is closed"
        with self._lock:
            if sub.regex is None:
                route = self._routes.get(sub.channel)
                if route is None:
                    route = _Route()
                    route.lcm_sub = self._lcm.subscribe(
                        lcm_literal(sub.channel), partial(self._on_exact, route)
                    )
                    route.lcm_sub.set_queue_capacity(self._capacity)
                    self._routes = {**self._routes, sub.channel: route}
                route.subs = (*route.subs, sub)
            else:
                self._patterns = (*self._patterns, sub)
                if self._star is None:
                    self._star = self._lcm.subscribe(".*", self._on_pattern)
                    self._star.set_queue_capacity(self._capacity)
            self._start()

    def remove(self, sub: Subscription) -> None:
        sub.active = False
        with self._lock:
            if sub.regex is None:
                route = self._routes.get(sub.channel)
                if route is None:
                    return
                route.subs = tuple(s for s in route.subs if s is not sub)
                if not route.subs:
                    route.retired = True
                    self._retire.append(route.lcm_sub)
                    self._routes = {k: v for k, v in self._routes.items() if v is not route}
            else:
                self._patterns = tuple(s for s in self._patterns if s is not sub)
                if not self._patterns and self._star is not None:
                    self._retire.append(self._star)
                    self._star = None

    def publish(self, channel: str, data: bytes) -> None:
        lc = self._lcm
        assert lc is not None, "bus is closed"
        lc.publish(channel, data)

    def _run(self) -> None:
        lc = self._lcm
        assert lc is not None
        while not self._stop.is_set():
            lc.handle_timeout(100)
            if self._retire:
                with self._lock:
                    retire, self._retire = self._retire, []
                for lcm_sub in retire:
                    lc.unsubscribe(lcm_sub)

    def _on_exact(self, route: _Route, channel: str, data: bytes) -> None:
        if route.retired:
            return
        self.received += 1
        subs = route.subs
        if len(subs) == 1:
            sub = subs[0]
            if not sub.active:
                return
            if sub.msg_type is None:
                msg: Any = data
            else:
                try:
                    msg = sub.msg_type.decode(data)
                except Exception as exc:  # noqa: BLE001 - any garbage must not kill the node
                    self._count_decode_error(channel, sub.msg_type, data, exc)
                    return
            try:
                sub.handler(channel, msg)
            except Exception:
                self.handler_errors += 1
                log.exception("handler for %s on %s raised; the bus carries on", channel, self.url)
            return
        self._deliver(channel, data, subs)

    def _on_pattern(self, channel: str, data: bytes) -> None:
        subs = tuple(s for s in self._patterns if s.regex is not None and s.regex.fullmatch(channel))
        if subs:
            self.received += 1
            self._deliver(channel, data, subs)

    def _deliver(self, channel: str, data: bytes, subs: tuple[Subscription, ...]) -> None:
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
                    except Exception as exc:  # noqa: BLE001
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
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self._lcm = None


class Bus(_BaseBus):
    """``antalate_lcm.bus.Bus`` with the prototype link (see the module docstring)."""

    def __init__(self, urls: Any, *, queue_capacity: int = DEFAULT_QUEUE_CAPACITY) -> None:
        super().__init__(urls, queue_capacity=queue_capacity)
        self._by_name: dict[str, _ProtoLink] = {}

    def _link(self, bus: str) -> _ProtoLink:  # type: ignore[override]
        link = self._by_name.get(bus)
        if link is not None:
            return link
        try:
            url = self.urls[bus]
        except KeyError:
            raise KeyError(f"unknown bus {bus!r}; declared: {', '.join(self.urls)}") from None
        with self._lock:
            if self._closed:
                raise RuntimeError("bus is closed")
            link = self._links.get(url)  # type: ignore[assignment]
            if link is None:
                link = _ProtoLink(url, self._queue_capacity, self._decode_log)
                self._links[url] = link  # type: ignore[assignment]
            self._by_name[bus] = link
            return link

    def publish(self, bus: str, channel: str, msg: Any) -> bool:
        link = self._by_name.get(bus) or self._link(bus)
        data = msg if isinstance(msg, (bytes, bytearray)) else msg.encode()
        try:
            link.publish(channel, data)
        except OSError as exc:
            self.publish_errors += 1
            self._publish_log.log(
                (bus, channel), logging.WARNING, "cannot send on %s %s: %s", bus, channel, exc
            )
            return False
        return True

    def close(self) -> None:
        self._by_name = {}
        super().close()
