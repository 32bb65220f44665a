"""LCM provider URLs: checked when the config is loaded, and diagnosed when liblcm refuses one.

liblcm (1.5) accepts ``provider://network?key=value&key=value`` for the providers below, warns on
stderr about an option it does not know and goes on, and answers every other mistake with the same
"Couldn't create LCM". So antalate checks a URL itself, with liblcm's own parsing rules (split at
``://``, then ``?``, ``&`` and ``=``; no percent-decoding), and says what was expected:

=========  ============================  ===================================================
provider   network                       options
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
                                         ``ca``, ``cert``, ``cert_key`` (PEM files: the CA the
                                         router's certificate must chain to; this node's
                                         certificate and key for mutual TLS), ``auth`` (a file
                                         holding ``user:password``), ``plain`` (1: allow ``tcp/``
                                         endpoints although TLS is configured)
=========  ============================  ===================================================

``zenoh://`` is antalate's own (not liblcm's): the same LCM-encoded bytes over Zenoh, one key
``PREFIX/CHANNEL`` per channel (:mod:`antalate_lcm.zenoh_bus`, docs/wan.md).

GROUP is a dotted IPv4 multicast address (224.0.0.0/4), PORT 1-65535 (sources: liblcm's
``lcm.h``, ``lcm.c``, ``lcm_udpm.c``, ``lcm_mpudpm.c``, ``lcm_file.c``, ``lcm_tcpq.c``).
"""

from __future__ import annotations

import errno
import ipaddress
import math
import re
import socket
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from antalate_lcm.errors import AntalateError, BusUnavailable, MulticastUnavailable

DEFAULT_UDPM = "239.255.76.67:7667"
DEFAULT_TCPQ = "127.0.0.1:7700"
EXAMPLES = "udpm://239.255.76.67:7667?ttl=1, memq:// or file:///path/to/log.lcm?mode=r"
_MULTICAST = ipaddress.IPv4Network("224.0.0.0/4")
_DECIMAL = re.compile(r"[0-9]+")
_HOSTNAME = re.compile(
    r"(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*"
)


@dataclass(frozen=True)
class LcmUrl:
    """A URL split the way liblcm splits it; ``host``/``port`` are set for the network providers."""

    url: str
    provider: str
    network: str
    options: dict[str, str] = field(default_factory=dict)
    host: str = ""
    port: int = 0

    @property
    def multicast(self) -> bool:
        return self.provider in ("udpm", "mpudpm")


def _int(name: str, low: int, high: int, what: str) -> Callable[[str], str | None]:
    def check(value: str) -> str | None:
        if _DECIMAL.fullmatch(value) and low <= int(value) <= high:
            return None
        return f"{what} for option {name}, not {value!r}"

    return check


def _speed(value: str) -> str | None:
    try:
        if math.isfinite(float(value)) and value.strip() == value:
            return None
    except ValueError:
        pass
    return f"a number for option speed (replay factor; <= 0 = as fast as possible), not {value!r}"


def _mode(value: str) -> str | None:
    return (
        None
        if value in ("r", "w", "a")
        else f"r (read), w (write) or a (append) for option mode, not {value!r}"
    )


_TTL = _int("ttl", 0, 255, "an integer 0-255 (0 = this host only, 1 = the local network)")
_RECV_BUF = _int("recv_buf_size", 1, 2**31 - 1, "a size in bytes, 1 to 2147483647")

#: Options each provider knows, each with its check (value -> problem or None).
OPTIONS: dict[str, dict[str, Callable[[str], str | None]]] = {
    "udpm": {"ttl": _TTL, "recv_buf_size": _RECV_BUF},
    "mpudpm": {
        "ttl": _TTL,
        "recv_buf_size": _RECV_BUF,
        "nports": _int("nports", 1, 65535, "a number of ports >= 1"),
    },
    "memq": {},
    "file": {
        "mode": _mode,
        "speed": _speed,
        "start_timestamp": _int("start_timestamp", 0, 2**63 - 1, "microseconds since 1970, >= 0"),
    },
    "tcpq": {},
    "zenoh": {
        "connect": lambda v: zenoh_endpoints_problem("connect", v),
        "listen": lambda v: zenoh_endpoints_problem("listen", v),
        "mode": lambda v: None if v in ("peer", "client") else f"peer or client for option mode, not {v!r}",
        "scout": lambda v: (
            None if v in ("0", "1") else f"0 or 1 for option scout (multicast scouting), not {v!r}"
        ),
        "express": lambda v: (
            None if v in ("0", "1") else f"0 or 1 for option express (no batching), not {v!r}"
        ),
        "lease": _int("lease", 500, 3_600_000, "a link lease in milliseconds, 500 to 3600000"),
        "config": lambda v: None if v else "the path of a Zenoh JSON5 config file for option config",
        "ca": lambda v: (
            None if v else "the path of a PEM file (the CA of the router's certificate) for option ca"
        ),
        "cert": lambda v: None if v else "the path of a PEM certificate for option cert",
        "cert_key": lambda v: None if v else "the path of the PEM private key of cert for option cert_key",
        "auth": lambda v: None if v else "the path of a file holding user:password for option auth",
        "plain": lambda v: None if v in ("0", "1") else f"0 or 1 for option plain, not {v!r}",
    },
}
PROVIDERS = tuple(OPTIONS)


#: Zenoh link protocols whose address is HOST:PORT (zenoh also has unixsock-stream/PATH).
_ZENOH_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
#: The ones that encrypt and authenticate (TLS; QUIC runs TLS 1.3).
ZENOH_SECURE_PROTOCOLS = ("tls", "quic")


def zenoh_plain_endpoints(endpoints: Sequence[str]) -> list[str]:
    """The endpoints that carry no TLS (``tcp/``, ``udp/``, ``ws/``; a Unix socket stays on the host)."""
    return [e for e in endpoints if e.partition("/")[0] not in (*ZENOH_SECURE_PROTOCOLS, "unixsock-stream")]


_ZENOH_CHUNK = re.compile(r"[^*$?#%/\s]+")


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
        if not colon or not (_HOSTNAME.fullmatch(bare) or _ip(bare)):
            return f"HOST:PORT after {proto}/ in option {option} ([v6]:PORT for IPv6), not {address!r}"
        if not (_DECIMAL.fullmatch(port) and 1 <= int(port) <= 65535):
            return f"a port 1-65535 in option {option}, not {port!r} (in {endpoint!r})"
    return None


def _ip(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def _zenoh(u: LcmUrl) -> LcmUrl:
    prefix = u.network or "antalate"
    if not all(_ZENOH_CHUNK.fullmatch(chunk) for chunk in prefix.split("/")):
        raise ValueError(
            f"a Zenoh key prefix after zenoh:// (chunks separated by /, none empty, no * $ ? # % or spaces), "
            f"not {u.network!r}"
        )
    opts = u.options
    if opts.get("mode") == "client" and "connect" not in opts:
        raise ValueError(
            "option connect with mode=client (the router to reach, e.g. connect=tcp/192.0.2.10:7447)"
        )
    if ("cert" in opts) != ("cert_key" in opts):
        raise ValueError("options cert and cert_key together (this node's certificate and its private key)")
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
    return LcmUrl(u.url, u.provider, prefix, opts)


def _split(url: str) -> LcmUrl:
    provider, sep, rest = url.partition("://")
    if not sep or not provider:
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
    return LcmUrl(url, provider, network, options)


def _group_and_port(u: LcmUrl, default: str) -> LcmUrl:
    network = u.network or default
    group, sep, port = network.partition(":")
    try:
        address = ipaddress.IPv4Address(group)
    except ValueError:
        raise ValueError(
            f"a dotted IPv4 multicast group (224.0.0.0 to 239.255.255.255) before the port, not {group!r}"
        ) from None
    if address not in _MULTICAST:
        raise ValueError(f"a multicast group (224.0.0.0/4); {group} is a unicast address")
    if not sep:
        raise ValueError(f"a port after the group ({group}:7667)")
    if not (_DECIMAL.fullmatch(port) and 1 <= int(port) <= 65535):
        raise ValueError(f"a port 1-65535 after the group, not {port!r}")
    return LcmUrl(u.url, u.provider, u.network, u.options, str(address), int(port))


def _host_and_port(u: LcmUrl) -> LcmUrl:
    network = u.network or DEFAULT_TCPQ
    host, sep, port = network.partition(":")
    if not _HOSTNAME.fullmatch(host):
        raise ValueError(f"a server HOST:PORT (an IPv4 address or a host name), not {network!r}")
    if sep and not (_DECIMAL.fullmatch(port) and 1 <= int(port) <= 65535):
        raise ValueError(f"a port 1-65535 after the host, not {port!r}")
    return LcmUrl(u.url, u.provider, u.network, u.options, host, int(port) if sep else 7700)


def parse_lcm_url(url: str) -> LcmUrl:
    """Split and check ``url``; raises ValueError saying what was expected (a phrase after 'expected')."""
    u = _split(url)
    known = OPTIONS.get(u.provider)
    if known is None:
        raise ValueError(
            f"an LCM provider ({', '.join(p + '://' for p in PROVIDERS)}), not {u.provider + '://'!r}: "
            f"e.g. {EXAMPLES}"
        )
    for key, value in u.options.items():
        check = known.get(key)
        if check is None:
            names = ", ".join(known) or "none"
            hint = " (obsolete: liblcm ignores it; remove it)" if key == "transmit_only" else ""
            raise ValueError(f"a known option of {u.provider}:// ({names}), not {key!r}{hint}")
        problem = check(value)
        if problem:
            raise ValueError(problem)
    if u.provider == "udpm":
        return _group_and_port(u, DEFAULT_UDPM)
    if u.provider == "mpudpm":
        u = _group_and_port(u, DEFAULT_UDPM)
        if u.port + int(u.options.get("nports", "1")) - 1 > 65535:
            raise ValueError(f"ports up to 65535: {u.port} + nports={u.options['nports']} goes beyond")
        return u
    if u.provider == "memq":
        if u.network:
            raise ValueError(f"nothing after memq:// (it is private to the process), not {u.network!r}")
        return u
    if u.provider == "zenoh":
        return _zenoh(u)
    if u.provider == "file":
        if not u.network:
            raise ValueError(
                "the path of an LCM log after file:// (file:///abs/path.lcm or file://rel/path.lcm)"
            )
        return u
    return _host_and_port(u)


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


def multicast_route_missing(u: LcmUrl) -> bool:
    """Whether this host has no route to ``u``'s multicast group (what liblcm's test connect() hits).

    A UDP connect() sends nothing: it only looks the destination up in the routing table.
    """
    if not u.multicast:
        return False
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.connect((u.host, u.port))
        except OSError as exc:
            return exc.errno in (errno.ENETUNREACH, errno.EHOSTUNREACH, errno.ENODEV)
    return False


#: Why an LCM tool cannot open a zenoh:// bus, and what to do instead.
ZENOH_NOT_LCM = (
    "a zenoh:// bus is antalate's own, not an LCM provider: the LCM tools (lcm-logger, lcm-spy) cannot "
    "open it; log or spy a LAN bus joined to it by antalate bridge (docs/wan.md)"
)


def open_failure(url: str, liblcm_said: Sequence[str] = ()) -> AntalateError:
    """The error to raise when liblcm could not create an instance for ``url``.

    Says "no multicast route" (with the fix) only when the routing table really has none; an
    invalid URL says what was expected; anything else repeats liblcm's own words.
    """
    try:
        u = parse_lcm_url(url)
    except ValueError as exc:
        return BusUnavailable(url, f"expected {exc}")
    if u.provider == "zenoh":
        return BusUnavailable(url, ZENOH_NOT_LCM)
    if multicast_route_missing(u):
        return MulticastUnavailable(url)
    said = " | ".join(line.strip() for line in liblcm_said if line.strip())
    return BusUnavailable(url, f"liblcm refused it ({said})" if said else "liblcm refused it")


__all__ = [
    "DEFAULT_UDPM",
    "OPTIONS",
    "PROVIDERS",
    "LcmUrl",
    "multicast_route_missing",
    "open_failure",
    "parse_lcm_url",
    "zenoh_endpoints_problem",
    "zenoh_plain_endpoints",
]
