"""The ``zenoh://`` transport: antalate's LCM-encoded messages over Zenoh, past the first router.

:class:`Zenoh` checks its URLs (endpoints, TLS, credentials) and opens a :class:`ZenohLCM`. That
offers the small part of ``lcm.LCM`` the bus uses -- ``publish``, ``subscribe`` (a channel regex
matched whole, as liblcm does) with ``set_queue_capacity``, ``unsubscribe``, ``handle``,
``handle_timeout`` and ``fileno`` -- so :class:`antalate_lcm.bus.Bus` drives it exactly like an LCM
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
import ipaddress
import json
import logging
import os
import re
import select
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

from antalate_lcm.errors import BusUnavailable
from antalate_lcm.ratelimit import RateLimitedLog, TokenBucket
from antalate_lcm.transports.base import (
    HOSTNAME,
    Connection,
    LcmUrl,
    OptionCheck,
    Transport,
    int_option,
    port_problem,
)

log = logging.getLogger("antalate.zenoh")

LcmHandler = Callable[..., None]

#: Attachment prefix of a sample a bridge forwarded (followed by the bridge's id).
BRIDGE_MARK = b"antalate-bridge:"
#: How long identical forwarded bytes on one channel count as the same message (s).
DEDUP_WINDOW = 2.0
#: Default link lease (ms): how long a silent link is kept before reconnecting.
DEFAULT_LEASE_MS = 3000
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

#: Why the LCM tools cannot open a zenoh:// bus, and what to do instead.
ZENOH_NOT_LCM = (
    "a zenoh:// bus is antalate's own, not an LCM provider: the LCM tools (lcm-logger, lcm-spy) cannot "
    "open it; log or spy a LAN bus joined to it by antalate bridge (docs/wan.md)"
)

#: Zenoh link protocols whose address is HOST:PORT (zenoh also has unixsock-stream/PATH).
_ZENOH_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
#: The ones that encrypt and authenticate (TLS; QUIC runs TLS 1.3).
ZENOH_SECURE_PROTOCOLS = ("tls", "quic")
_ZENOH_CHUNK = re.compile(r"[^*$?#%/\s]+")


def zenoh_plain_endpoints(endpoints: Sequence[str]) -> list[str]:
    """The endpoints that carry no TLS (``tcp/``, ``udp/``, ``ws/``; a Unix socket stays on the host)."""
    return [e for e in endpoints if e.partition("/")[0] not in (*ZENOH_SECURE_PROTOCOLS, "unixsock-stream")]


def zenoh_endpoints_problem(option: str, value: str) -> str | None:
    """A problem with a comma-separated list of Zenoh endpoints (``tcp/10.0.0.3:7447``), or None."""
    if not value:
        return f"Zenoh endpoints for option {option}, e.g. {option}=tcp/192.0.2.10:7447"
    for endpoint in value.split(","):
        proto, sep, address = endpoint.partition("/")
        if proto == "unixsock-stream" and sep and address:
            continue
        if proto not in _ZENOH_PROTOCOLS or not sep:
            return (
                f"a Zenoh endpoint PROTOCOL/HOST:PORT ({', '.join(_ZENOH_PROTOCOLS)}, unixsock-stream/PATH) "
                f"for option {option}, not {endpoint!r}"
            )
        host, colon, port = address.rpartition(":")
        bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
        if not colon or not (HOSTNAME.fullmatch(bare) or _ip(bare)):
            return f"HOST:PORT after {proto}/ in option {option} ([v6]:PORT for IPv6), not {address!r}"
        problem = port_problem(port, f"in option {option}")
        if problem:
            return f"{problem} (in {endpoint!r})"
    return None


def _ip(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def _one_of(values: tuple[str, ...], expected: str) -> OptionCheck:
    return lambda v: None if v in values else f"{expected}, not {v!r}"


def _path(what: str) -> OptionCheck:
    return lambda v: None if v else what


class Zenoh(Transport):
    """antalate's own: one Zenoh key ``PREFIX/CHANNEL`` per channel, through routers (docs/wan.md)."""

    scheme = "zenoh"
    options: ClassVar[dict[str, OptionCheck]] = {
        "connect": lambda v: zenoh_endpoints_problem("connect", v),
        "listen": lambda v: zenoh_endpoints_problem("listen", v),
        "mode": _one_of(("peer", "client"), "peer or client for option mode"),
        "scout": _one_of(("0", "1"), "0 or 1 for option scout (multicast scouting)"),
        "express": _one_of(("0", "1"), "0 or 1 for option express (no batching)"),
        "lease": int_option("lease", 500, 3_600_000, "a link lease in milliseconds, 500 to 3600000"),
        "config": _path("the path of a Zenoh JSON5 config file for option config"),
        "ca": _path("the path of a PEM file (the CA of the router's certificate) for option ca"),
        "cert": _path("the path of a PEM certificate for option cert"),
        "cert_key": _path("the path of the PEM private key of cert for option cert_key"),
        "auth": _path("the path of a file holding user:password for option auth"),
        "plain": _one_of(("0", "1"), "0 or 1 for option plain"),
    }
    not_lcm = ZENOH_NOT_LCM

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        prefix = u.network or "antalate"
        if not all(_ZENOH_CHUNK.fullmatch(chunk) for chunk in prefix.split("/")):
            raise ValueError(
                "a Zenoh key prefix after zenoh:// (chunks separated by /, none empty, no * $ ? # % or "
                f"spaces), not {u.network!r}"
            )
        opts = u.options
        if opts.get("mode") == "client" and "connect" not in opts:
            raise ValueError(
                "option connect with mode=client (the router to reach, e.g. connect=tcp/192.0.2.10:7447)"
            )
        if ("cert" in opts) != ("cert_key" in opts):
            raise ValueError(
                "options cert and cert_key together (this node's certificate and its private key)"
            )
        if ("ca" in opts or "cert" in opts) and opts.get("plain") != "1":
            # TLS configured: a tcp/ endpoint would send the swarm's traffic in clear to whoever answers
            plain = zenoh_plain_endpoints(
                [e for o in ("connect", "listen") for e in opts.get(o, "").split(",") if e]
            )
            if plain:
                raise ValueError(
                    f"tls/ or quic/ endpoints with TLS configured (ca/cert), not {', '.join(plain)} "
                    "(add plain=1 to allow an unencrypted endpoint)"
                )
        return LcmUrl(u.url, u.scheme, prefix, opts)

    def open(self, *, max_message_size: int | None = None) -> Connection:
        return ZenohLCM(self.url.url, max_message_size=max_message_size)


class GroupProof(Protocol):
    """Signs and checks election tokens (:class:`antalate_lcm.security.MemberProof`, with the swarm key);
    a protocol here so the transport does not depend on the security module that asks it."""

    @property
    def refresh(self) -> float: ...

    def token(self, group: str, member: str, now: float) -> str: ...

    def check(self, group: str, name: str, now: float) -> tuple[str, float] | str: ...

    def fresh(self, t: float, now: float) -> bool: ...


_SPECIAL = ".^$*+?()[]{}|\\"
_LITERAL = re.compile(r"(?:[^.^$*+?()\[\]{}|\\]|\\[.^$*+?()\[\]{}|\\])*")
#: Characters a Zenoh key cannot hold (wildcards, verbatim-chunk ``@``), escaped as %XX in a channel.
_KEY_UNSAFE = re.compile(r"[%*$?#@\s]")
_EMPTY_CHUNK = "%-"


def channel_key(prefix: str, channel: str) -> str:
    """The Zenoh key of ``channel``: ``prefix/channel``, reserved characters and empty chunks escaped."""
    chunks = [
        _KEY_UNSAFE.sub(lambda m: f"%{ord(m.group()):02X}", c) if c else _EMPTY_CHUNK
        for c in channel.split("/")
    ]
    return f"{prefix}/{'/'.join(chunks)}"


def key_channel(prefix: str, key: str) -> str | None:
    """The channel a key under ``prefix`` carries (inverse of :func:`channel_key`); None if not ours."""
    if not key.startswith(prefix + "/"):
        return None
    out = []
    for chunk in key[len(prefix) + 1 :].split("/"):
        if chunk == _EMPTY_CHUNK:
            out.append("")
        else:
            out.append(re.sub(r"%([0-9A-F]{2})", lambda m: chr(int(m.group(1), 16)), chunk))
    return "/".join(out)


def literal_channel(regex: str) -> str | None:
    """The one channel an LCM channel regex matches when it is a literal (``alpha/MC_STATE``), else None."""
    if not _LITERAL.fullmatch(regex):
        return None
    return re.sub(r"\\(.)", r"\1", regex)


def zenoh_config(u: LcmUrl, *, max_message_size: int | None = None) -> Any:
    """A ``zenoh.Config`` for a parsed ``zenoh://`` URL. Multicast scouting is off unless ``scout=1``:
    a bus reaches exactly the endpoints its config names, never whatever answers on the LAN."""
    import zenoh

    opts = u.options
    config = zenoh.Config.from_file(opts["config"]) if "config" in opts else zenoh.Config()
    if "mode" in opts:
        config.insert_json5("mode", json.dumps(opts["mode"]))
    elif "config" not in opts:
        config.insert_json5(
            "mode", json.dumps("client" if "connect" in opts and "listen" not in opts else "peer")
        )
    for option in ("connect", "listen"):
        if option in opts:
            config.insert_json5(f"{option}/endpoints", json.dumps(opts[option].split(",")))
    if "scout" in opts or "config" not in opts:
        enabled = json.dumps(opts.get("scout") == "1")
        config.insert_json5("scouting/multicast/enabled", enabled)
        config.insert_json5("scouting/gossip/enabled", "true")
    if "config" not in opts:
        # Field links come back: retry a lost router quickly and keep retrying forever.
        retry = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
        config.insert_json5("connect/retry", json.dumps(retry))
        config.insert_json5("connect/timeout_ms", json.dumps({"router": -1, "peer": -1, "client": 0}))
        config.insert_json5(
            "connect/exit_on_failure", json.dumps({"router": False, "peer": False, "client": False})
        )
        config.insert_json5("listen/exit_on_failure", "true")
    if "lease" in opts or "config" not in opts:
        # A cut link is noticed within the lease (Zenoh's default, 10 s, outlives a short outage's
        # TCP backoff), then the client reconnects at most 1 s after the link is back.
        config.insert_json5("transport/link/tx/lease", opts.get("lease", str(DEFAULT_LEASE_MS)))
    if max_message_size is not None:
        config.insert_json5("transport/link/rx/max_message_size", str(max_message_size))
    tls = tls_settings(ca=opts.get("ca"), cert=opts.get("cert"), key=opts.get("cert_key"))
    if tls:
        config.insert_json5("transport/link/tls", json.dumps(tls))
    if "auth" in opts:
        user, password = read_credentials(opts["auth"])
        config.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    return config


def readable_file(path: str, what: str) -> str:
    """``path`` made absolute, or ValueError naming ``what`` (Zenoh's own error is a Rust backtrace)."""
    p = os.path.abspath(os.path.expanduser(path))
    if not os.access(p, os.R_OK) or not os.path.isfile(p):
        raise ValueError(f"{what} {path!r} is not a readable file")
    return p


def tls_settings(
    *, ca: str | None = None, cert: str | None = None, key: str | None = None, listen: bool = False
) -> dict[str, Any]:
    """Zenoh's ``transport/link/tls`` for PEM files, all of them paths (never inline secrets).

    ``ca``: the CA a peer's certificate must chain to (a client checks the router's; a router with
    it asks every client for a certificate: mutual TLS). ``cert``/``key``: this node's own, shown to
    the router (client) or to clients (``listen``)."""
    tls: dict[str, Any] = {}
    if ca:
        tls["root_ca_certificate"] = readable_file(ca, "the CA certificate")
    if cert and key:
        side = "listen" if listen else "connect"
        tls[f"{side}_certificate"] = readable_file(cert, "the certificate")
        tls[f"{side}_private_key"] = readable_file(key, "the private key")
        if not listen:
            tls["enable_mtls"] = True  # without it Zenoh's client never shows its certificate
    if listen and ca:
        tls["enable_mtls"] = True
    return tls


def read_credentials(path: str) -> tuple[str, str]:
    """``user:password`` from the first line of a file (the secret stays out of the config file)."""
    line = Path(readable_file(path, "the credentials file")).read_text().splitlines()
    user, sep, password = (line[0] if line else "").strip().partition(":")
    if not sep or not user or not password:
        raise ValueError(f"the credentials file {path!r} must hold one line user:password")
    return user, password


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


@dataclass(eq=False)
class _Group:
    """Who is in one group: the live token names of each member (pure; the clock is passed)."""

    key: str
    group: str
    member: str
    on_change: Callable[[frozenset[str]], None]
    proof: GroupProof | None = None
    #: member -> {token name: the time it proves (0 without a proof)}
    tokens: dict[str, dict[str, float]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    report_lock: threading.Lock = field(default_factory=threading.Lock)
    reported: frozenset[str] | None = None
    token: Any = None
    sub: Any = None

    def seen(self, name: str, alive: bool, now: float) -> str | None:
        """A token appeared or went away; why it does not count, or None."""
        if self.proof is None:
            who, t = name, 0.0
        else:
            checked = self.proof.check(self.group, name, now)
            if isinstance(checked, str):
                return None if not alive else checked  # a forged token going away changes nothing
            who, t = checked
        with self.lock:
            if alive:
                self.tokens.setdefault(who, {})[name] = t
            else:
                mine = self.tokens.get(who, {})
                mine.pop(name, None)
                if not mine:
                    self.tokens.pop(who, None)
        return None

    def expire(self, now: float) -> None:
        if self.proof is None:
            return
        with self.lock:
            for who in list(self.tokens):
                fresh = {n: t for n, t in self.tokens[who].items() if self.proof.fresh(t, now)}
                if fresh:
                    self.tokens[who] = fresh
                else:
                    del self.tokens[who]

    def members(self) -> frozenset[str]:
        with self.lock:
            return frozenset(self.tokens) | {self.member}

    def report(self) -> None:
        """Tell ``on_change`` the members if they changed (in order: Zenoh's and the refresher's threads)."""
        with self.report_lock:
            members = self.members()
            if members != self.reported:
                self.reported = members
                self.on_change(members)


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
    "read_credentials",
    "readable_file",
    "tls_settings",
]
