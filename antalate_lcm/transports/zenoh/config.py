"""A ``zenoh://`` URL: what its key prefix and options may be, and the ``zenoh.Config`` it becomes.

Endpoints, TLS files and credentials are checked when the config is loaded, with what was expected;
Zenoh's own answer to a missing file is a Rust backtrace.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from antalate_lcm.transports.base import HOSTNAME, LcmUrl, OptionCheck, int_option, port_problem

#: Default link lease (ms): how long a silent link is kept before reconnecting.
DEFAULT_LEASE_MS = 3000
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


#: What each option of a zenoh:// URL must be.
OPTIONS: dict[str, OptionCheck] = {
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


def check_url(u: LcmUrl) -> LcmUrl:
    """``u`` with its key prefix (``antalate`` when empty) and its options checked together."""
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
    return LcmUrl(u.url, u.scheme, prefix, opts)


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
