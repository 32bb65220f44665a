"""What every transport is: a URL scheme, what its URLs may say, whether other hosts reach it, and how
it opens.

A bus URL is ``scheme://network?key=value&key=value``. liblcm (1.5) accepts that for its own providers,
warns on stderr about an option it does not know and goes on, and answers every other mistake with the
same "Couldn't create LCM". So each transport checks its URLs itself, with liblcm's own parsing rules
(split at ``://``, then ``?``, ``&`` and ``=``; no percent-decoding; sources: liblcm's ``lcm.h``,
``lcm.c``), and says what was expected. The transports and their URLs (one module each, registered by
scheme in :mod:`antalate_lcm.transports`):

=========  ============================  ===================================================
scheme     network                       options
=========  ============================  ===================================================
udpm       ``GROUP:PORT`` (empty: the    ``ttl`` (0-255; 0 = this host only), ``recv_buf_size``
           default 239.255.76.67:7667)   (bytes)
mpudpm     ``GROUP:FIRST_PORT``          ``ttl``, ``recv_buf_size``, ``nports`` (ports used)
memq       empty                         none (in-process only)
file       ``PATH`` of an LCM log        ``mode`` (r, w or a), ``speed`` (replay factor; <= 0
                                         as fast as possible), ``start_timestamp`` (µs)
tcpq       ``HOST:PORT`` (empty:         none (needs an LCM TCP queue server)
           127.0.0.1:7700)
zenoh      key prefix (empty:            ``connect``, ``listen`` (comma-separated Zenoh endpoints
           ``antalate``)                 ``tcp/HOST:PORT``), ``mode`` (peer or client), ``scout``
                                         (0/1: multicast scouting), ``express`` (0/1: no batching),
                                         ``lease`` (ms a silent link lives; default 3000),
                                         ``config`` (a Zenoh JSON5 file applied first);
                                         ``ca``, ``cert``, ``cert_key`` (PEM files), ``auth`` (a
                                         file holding ``user:password``), ``plain`` (1: allow
                                         ``tcp/`` endpoints although TLS is configured)
=========  ============================  ===================================================

``zenoh://`` is antalate's own (not liblcm's): the same LCM-encoded bytes over Zenoh
(:mod:`antalate_lcm.transports.zenoh`, docs/wan.md). Every other scheme is opened by liblcm.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import tempfile
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import lcm

from antalate_lcm.base.errors import AntalateError, BusUnavailable

log = logging.getLogger("antalate.bus")

#: What an option's value must be: the value -> the problem (a phrase after "expected"), or None.
OptionCheck = Callable[[str], "str | None"]

DECIMAL = re.compile(r"[0-9]+")
HOSTNAME = re.compile(
    r"(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*"
)


@dataclass(frozen=True)
class LcmUrl:
    """A URL split the way liblcm splits it; ``host``/``port`` are set for the network transports."""

    url: str
    scheme: str
    network: str
    options: dict[str, str] = field(default_factory=dict)
    host: str = ""
    port: int = 0


#: What bus URLs look like, for messages that say what was expected.
EXAMPLES = "udpm://239.255.76.67:7667?ttl=1, memq:// or file:///path/to/log.lcm?mode=r"


def split_url(url: str) -> LcmUrl:
    """``url`` split at ``://``, ``?``, ``&`` and ``=`` as liblcm splits it (an option given twice is
    refused: liblcm would keep one silently)."""
    scheme, sep, rest = url.partition("://")
    if not sep or not scheme:
        raise ValueError(f"an LCM URL provider://network?options such as {EXAMPLES}")
    network, *queries = rest.split("?")
    options: dict[str, str] = {}
    for query in queries:
        for pair in query.split("&"):
            key, _, value = pair.partition("=")
            if not key:
                continue
            if key in options:
                raise ValueError(f"option {key} once (it is given twice)")
            options[key] = value
    return LcmUrl(url, scheme, network, options)


def int_option(name: str, low: int, high: int, what: str) -> OptionCheck:
    def check(value: str) -> str | None:
        if DECIMAL.fullmatch(value) and low <= int(value) <= high:
            return None
        return f"{what} for option {name}, not {value!r}"

    return check


def port_problem(port: str, where: str) -> str | None:
    """What is wrong with the decimal port ``port`` found ``where`` (None: 1-65535)."""
    if DECIMAL.fullmatch(port) and 1 <= int(port) <= 65535:
        return None
    return f"a port 1-65535 {where}, not {port!r}"


#: Held while fd 2 is swapped for a file (`captured_stderr`). fd 2 belongs to the whole process: a
#: child started by another thread meanwhile inherits the file as its stderr and every line it
#: writes is lost (an agent process of ``antalate run --processes`` once lost all of its own), so
#: whatever starts a child that writes to this process's stderr takes it first (`spawn_lock`).
_FD2 = threading.RLock()


def spawn_lock() -> threading.RLock:
    """The lock to hold while starting a child that inherits this process's stderr."""
    return _FD2


@contextlib.contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """Swallow what liblcm prints on fd 2 (opening sockets, reading a damaged log): our errors say it better.

    The yielded list holds the swallowed lines once the block ends (for a debug log). Another
    thread's log lines written meanwhile land there too: `Transport.open_lcm` writes them back.
    """
    lines: list[str] = []
    with _FD2, tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = os.dup(2)
        try:
            os.dup2(tmp.fileno(), 2)
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(tmp.read().decode(errors="replace").splitlines())


class Connection(Protocol):
    """An open transport: the part of ``lcm.LCM`` the bus and the bridge drive.

    ``fileno()`` is its readiness on the event loop: readable when ``handle_timeout(0)`` has a message
    to deliver. A connection that holds resources of its own (a Zenoh session) has ``close()`` too;
    liblcm frees an instance when it is deallocated.
    """

    def publish(self, channel: str, data: bytes) -> None: ...

    def subscribe(self, channel: str, handler: Callable[[str, bytes], None]) -> Any: ...

    def unsubscribe(self, sub: Any) -> None: ...

    def handle(self) -> object: ...

    def handle_timeout(self, timeout_ms: int) -> int: ...

    def fileno(self) -> int: ...


class Transport(ABC):
    """One URL scheme's way to carry LCM-encoded messages (httpx's transports, cflib's link drivers).

    A class states what is true of every URL of its scheme; an instance is one parsed URL
    (:func:`antalate_lcm.transports.transport_for`), which the bus, the bridge, the exposure policy
    and the CLI ask instead of reading the URL's text.
    """

    #: The URL scheme it serves (``udpm`` for ``udpm://…``).
    scheme: ClassVar[str]
    #: What each option of its URLs must be.
    options: ClassVar[Mapping[str, OptionCheck]] = {}
    #: Datagrams from other hosts can arrive on it (the insecure-exposure policy asks this).
    network_reachable: ClassVar[bool] = True
    #: Why the LCM tools (lcm-spy, lcm-logger) cannot open it; empty: liblcm opens it, so they can.
    not_lcm: ClassVar[str] = ""
    #: liblcm's notify pipe is readable exactly while a message is queued (udpm, memq), so a readable
    #: descriptor means ``handle()`` returns at once.
    ready_means_message: ClassVar[bool] = False
    #: Its messages reach only this instance's subscribers (memq): the bus queues them on its loop.
    in_process: ClassVar[bool] = False
    #: Other processes can hear it (False: memq, and file://'s log, which no running process shares):
    #: ``antalate run --processes`` needs it for the buses it commands and records on.
    crosses_processes: ClassVar[bool] = True
    #: Runs side by side that must not hear each other (``antalate sweep --jobs``) each take a port
    #: of their own on it (:meth:`for_slot`).
    apart_by_port: ClassVar[bool] = False

    def __init__(self, url: LcmUrl) -> None:
        self.url = url

    @classmethod
    def parse(cls, url: str) -> LcmUrl:
        """Split and check ``url``; ValueError says what was expected (a phrase after 'expected')."""
        u = split_url(url)
        if u.scheme != cls.scheme:
            raise ValueError(f"a {cls.scheme}:// URL, not {url!r}")
        for key, value in u.options.items():
            check = cls.options.get(key)
            if check is None:
                names = ", ".join(cls.options) or "none"
                hint = " (obsolete: liblcm ignores it; remove it)" if key == "transmit_only" else ""
                raise ValueError(f"a known option of {cls.scheme}:// ({names}), not {key!r}{hint}")
            problem = check(value)
            if problem:
                raise ValueError(problem)
        return cls.check(u)

    @classmethod
    @abstractmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        """``u`` with its network part checked (and host and port filled in where there are some):
        what that part means is each transport's own."""

    def for_slot(self, slot: int, step: int) -> str:
        """This bus's URL for the ``slot``-th (from 0) of runs side by side that must not hear each
        other: ``step * slot`` ports further where the transport is kept apart by port (udpm),
        else the URL as it is (memq and file stay in their process; a tcpq server and mpudpm's port
        range are the user's). ValueError says why runs cannot be kept apart on it (zenoh)."""
        u = self.url
        if not self.apart_by_port or not slot:
            return u.url
        port = u.port + step * slot
        if port > 65535:
            raise ValueError(f"no port for parallel slot {slot} ({port} > 65535): use fewer --jobs")
        _, sep, query = u.url.partition("?")
        return f"{u.scheme}://{u.host}:{port}{sep}{query}"

    def open(self, *, max_message_size: int | None = None) -> Connection:
        """A connection to this URL: liblcm's provider, unless the transport is antalate's own.

        ``max_message_size``: where the transport can drop a larger incoming message before
        reassembling it (Zenoh), it does; liblcm's providers cannot, and accept up to their own limit.
        """
        return self.open_lcm()

    def open_lcm(self) -> Connection:
        """liblcm's instance for this URL, or the error that says the fix (liblcm says only
        "Couldn't create LCM" and prints the reason, if any, on stderr)."""
        if self.not_lcm:
            raise BusUnavailable(self.url.url, self.not_lcm)
        try:
            with captured_stderr() as noise:
                instance: Connection = lcm.LCM(self.url.url)
        except (RuntimeError, OSError):
            log.debug("liblcm said: %s", " | ".join(noise))
            raise self.failure(noise) from None
        if noise:  # liblcm is silent when it succeeds: these are other threads' lines, not lost
            sys.stderr.write("".join(line + "\n" for line in noise))
            sys.stderr.flush()
        return instance

    def failure(self, liblcm_said: Sequence[str] = ()) -> AntalateError:
        """The error to raise when this URL could not be opened; repeats liblcm's own words."""
        said = " | ".join(line.strip() for line in liblcm_said if line.strip())
        return BusUnavailable(self.url.url, f"liblcm refused it ({said})" if said else "liblcm refused it")


__all__ = ["Connection", "LcmUrl", "Transport", "captured_stderr", "spawn_lock"]
