"""Transports: how a bus URL's messages travel, one module per URL scheme, chosen by the scheme alone.

As cflib picks a link driver by the URI's scheme and httpx puts every transport behind one interface,
antalate maps a bus URL's scheme to its :class:`~antalate_lcm.transports.base.Transport` here, in
:data:`TRANSPORTS`, and nowhere else: the bus opens what :func:`transport_for` gives it, the bridge
asks it how to read a side, the exposure policy asks it whether other hosts reach a bus, and the CLI
asks it whether the LCM tools can open one. A URL whose scheme no transport serves, or that breaks
its transport's rules, is refused here with what was expected (the known schemes, or the rule).

======  ================================  =====================================================
scheme  module                            what carries the messages
======  ================================  =====================================================
udpm    :mod:`.udpm`                      UDP multicast on the LAN (antalate's own reader)
mpudpm  :mod:`.udpm`                      liblcm's multi-port UDP multicast
memq    :mod:`.memq`                      the process's memory (an agent's private bus)
file    :mod:`.file`                      an LCM log, replayed or recorded
tcpq    :mod:`.tcpq`                      an LCM TCP queue server
zenoh   :mod:`.zenoh`                     Zenoh routers, across networks (docs/wan.md)
======  ================================  =====================================================

:mod:`.datagram` is LCM's udpm wire format, read without liblcm (the udpm reader and the bridge).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from antalate_lcm.base.errors import AntalateError, InvalidBusUrl, UnknownTransport
from antalate_lcm.transports.base import EXAMPLES, Connection, LcmUrl, Transport, captured_stderr, spawn_lock
from antalate_lcm.transports.file import File
from antalate_lcm.transports.memq import Memq
from antalate_lcm.transports.tcpq import Tcpq
from antalate_lcm.transports.udpm import Mpudpm, Udpm
from antalate_lcm.transports.zenoh import Zenoh

#: The one map from a URL scheme to its transport.
TRANSPORTS: Mapping[str, type[Transport]] = {t.scheme: t for t in (Udpm, Mpudpm, Memq, File, Tcpq, Zenoh)}


def _transport_class(url: str) -> type[Transport] | None:
    """The transport class of ``url``'s scheme (None: no transport serves it); ValueError: no scheme."""
    scheme, sep, _ = url.partition("://")
    if not sep or not scheme:
        raise ValueError(f"an LCM URL provider://network?options such as {EXAMPLES}")
    return TRANSPORTS.get(scheme)


def _unknown(url: str) -> str:
    scheme = url.partition("://")[0] + "://"
    return f"an LCM provider ({', '.join(s + '://' for s in TRANSPORTS)}), not {scheme!r}: e.g. {EXAMPLES}"


def parse_lcm_url(url: str) -> LcmUrl:
    """Split and check ``url`` by its transport's rules; ValueError says what was expected (a phrase
    after 'expected'), the known schemes when no transport serves this one."""
    cls = _transport_class(url)
    if cls is None:
        raise ValueError(_unknown(url))
    return cls.parse(url)


def transport_for(url: str) -> Transport:
    """The transport of ``url``, its URL checked: an unknown scheme is an :class:`UnknownTransport`
    naming the known ones, any other mistake an :class:`InvalidBusUrl` saying what was expected."""
    try:
        cls = _transport_class(url)
        if cls is not None:
            return cls(cls.parse(url))
    except ValueError as exc:
        raise InvalidBusUrl(url, f"expected {exc}") from None
    raise UnknownTransport(url, f"expected {_unknown(url)}")


def bus_url_problem(buses: Mapping[str, str]) -> tuple[str, str] | None:
    """The first ``[buses]`` entry whose URL does not parse, as (``buses.NAME``, what was expected):
    checked at load time by every file with buses, since liblcm's answer to any mistake is "Couldn't
    create LCM"."""
    for name, url in buses.items():
        try:
            parse_lcm_url(url)
        except ValueError as exc:
            return f"buses.{name}", str(exc)
    return None


def open_lcm(url: str) -> Connection:
    """liblcm's instance for ``url`` (what the LCM tools would open), or the error that says the fix:
    a URL they cannot open (zenoh://) says what to do instead."""
    return transport_for(url).open_lcm()


def open_failure(url: str, liblcm_said: Sequence[str] = ()) -> AntalateError:
    """The error to raise when ``url`` could not be opened: an invalid URL says what was expected, a
    missing multicast route says the fix (only when the routing table really has none), anything else
    repeats liblcm's own words."""
    try:
        return transport_for(url).failure(liblcm_said)
    except InvalidBusUrl as exc:
        return exc


__all__ = [
    "EXAMPLES",
    "TRANSPORTS",
    "Connection",
    "LcmUrl",
    "Transport",
    "bus_url_problem",
    "captured_stderr",
    "spawn_lock",
    "open_failure",
    "open_lcm",
    "parse_lcm_url",
    "transport_for",
]
