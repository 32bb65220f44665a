"""``antalate router``: a Zenoh router in its own process, for the sites' bridges and agents to reach.

It is eclipse-zenoh's router mode, with what antalate's buses assume: no multicast scouting (a
router at a site must not pull in whatever Zenoh nodes answer on its LAN) and the same short link
lease as the buses (:data:`antalate_lcm.transports.zenoh.DEFAULT_LEASE_MS`), so a cut link is noticed
and re-made quickly.

Who may use it (issue 29: anyone who reached the router could listen to every position and command
and feed every bridge whatever it liked):

* ``--tls-cert``/``--tls-key``: its endpoints are ``tls/`` (or ``quic/``), encrypted; a ``tcp/``
  endpoint is refused unless ``--plain`` says so.
* ``--ca``: mutual TLS, every client shows a certificate signed by that CA (one per site); anyone
  else's TLS handshake fails before a Zenoh session exists.
* ``--users``: a Zenoh ``user:password`` dictionary file; a client must know a pair.
* Access control, always on: a client may put, subscribe, query and declare liveliness tokens only
  under the swarm's prefixes (``--prefix``, default ``antalate``: keys ``antalate/**`` and the
  bridges' election groups ``antalate-groups/**``); everything else is denied at the router.

The secrets stay in files (PEM keys, the users file); the command line and the configs hold paths.
``antalate lab-ca`` makes a throw-away CA and certificates for a lab (docs/wan.md); a production
router (storage, the REST plugin) can be ``zenohd`` with the same settings in its config file.
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.runtime.launch import wait_for_stop
from antalate_lcm.transports.zenoh import zenoh_endpoints_problem, zenoh_plain_endpoints

if TYPE_CHECKING:  # the zenoh extra is optional: imported where used
    import zenoh

log = logging.getLogger("antalate.router")

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
DEFAULT_TLS_LISTEN = "tls/0.0.0.0:7447"
DEFAULT_PREFIX = "antalate"
#: Every kind of Zenoh message a swarm's client sends or receives, all allowed under its prefixes.
ACL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)


def access_control(prefixes: list[str]) -> dict[str, object]:
    """Zenoh's ``access_control``: deny by default, allow every message under each prefix and its
    election groups (``PREFIX-groups``, :meth:`antalate_lcm.transports.zenoh.ZenohLCM.join_group`)."""
    keys = [k for p in prefixes for k in (f"{p}/**", f"{p}-groups/**")]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {
                "id": "swarm",
                "permission": "allow",
                "flows": ["ingress", "egress"],
                "messages": list(ACL_MESSAGES),
                "key_exprs": keys,
            }
        ],
        "subjects": [{"id": "every-client"}],
        "policies": [{"rules": ["swarm"], "subjects": ["every-client"]}],
    }


def router_config(
    listen: list[str],
    lease_ms: int,
    *,
    tls_cert: str | None = None,
    tls_key: str | None = None,
    ca: str | None = None,
    users: str | None = None,
    prefixes: list[str] | None = None,
) -> zenoh.Config:
    import zenoh

    from antalate_lcm.transports.zenoh import tls_settings

    config: zenoh.Config = zenoh.Config()  # zenoh's stub returns typing.Self, Any before 3.11
    config.insert_json5("mode", json.dumps("router"))
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tx/lease", str(lease_ms))
    try:
        tls = tls_settings(ca=ca, cert=tls_cert, key=tls_key, listen=True)
        if users:
            config.insert_json5("transport/auth/usrpwd", json.dumps({"dictionary_file": _users_file(users)}))
    except ValueError as exc:
        raise AntalateError(str(exc)) from None
    if tls:
        config.insert_json5("transport/link/tls", json.dumps(tls))
    if prefixes is not None:
        config.insert_json5("access_control", json.dumps(access_control(prefixes)))
    return config


def _users_file(path: str) -> str:
    """The users file made absolute, checked for ``user:password`` lines (Zenoh would only log)."""
    from antalate_lcm.transports.zenoh import readable_file

    p = readable_file(path, "the users file")
    for n, line in enumerate(Path(p).read_text().splitlines(), 1):
        user, sep, password = line.strip().partition(":")
        if line.strip() and not (sep and user and password):
            raise ValueError(f"the users file {path!r}, line {n}: expected user:password")
    return p


def run_router(
    listen: list[str],
    *,
    lease_ms: int,
    stop: threading.Event | None = None,
    tls_cert: str | None = None,
    tls_key: str | None = None,
    ca: str | None = None,
    users: str | None = None,
    prefixes: list[str] | None = None,
    plain: bool = False,
) -> int:
    """Listen on ``listen`` until SIGINT/SIGTERM (or ``stop``)."""
    for endpoint in listen:
        problem = zenoh_endpoints_problem("--listen", endpoint)
        if problem:
            raise AntalateError(f"expected {problem}")
    if bool(tls_cert) != bool(tls_key):
        raise AntalateError("expected --tls-cert and --tls-key together (the router's certificate and key)")
    if ca and not tls_cert:
        raise AntalateError("expected --tls-cert and --tls-key with --ca (mutual TLS needs the router's own)")
    clear = zenoh_plain_endpoints(listen)
    if tls_cert and clear and not plain:
        raise AntalateError(
            f"refusing to listen on {', '.join(clear)} with TLS configured: the swarm's traffic would "
            "cross in clear. Listen on tls/HOST:PORT, or pass --plain"
        )
    try:
        import zenoh
    except ImportError:
        raise AntalateError("the Zenoh library is not installed: pip install 'antalate[zenoh]'") from None
    config = router_config(
        listen, lease_ms, tls_cert=tls_cert, tls_key=tls_key, ca=ca, users=users, prefixes=prefixes
    )
    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        raise AntalateError(f"the Zenoh router cannot listen on {', '.join(listen)}: {exc}") from None
    who = [
        "mutual TLS" if ca else "TLS" if tls_cert else "NO TLS",
        "users file" if users else "",
        f"keys under {', '.join(prefixes)} only" if prefixes else "",
    ]
    print(
        f"zenoh router {session.zid()} listening on {', '.join(listen)} ({', '.join(w for w in who if w)})",
        flush=True,
    )
    if not tls_cert and not users:
        log.warning(
            "the router admits anyone who reaches %s: give --tls-cert/--tls-key/--ca or --users (docs/wan.md)",
            ", ".join(listen),
        )
    try:
        wait_for_stop(stop)
    finally:
        session.close()
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    from antalate_lcm.transports.zenoh import DEFAULT_LEASE_MS

    listen = args.listen or [DEFAULT_TLS_LISTEN if args.tls_cert else DEFAULT_LISTEN]
    return run_router(
        listen,
        lease_ms=args.lease or DEFAULT_LEASE_MS,
        tls_cert=args.tls_cert,
        tls_key=args.tls_key,
        ca=args.ca,
        users=args.users,
        prefixes=args.prefix or [DEFAULT_PREFIX],
        plain=args.plain,
    )


def run_bridge(config_path: str, *, stop: threading.Event | None = None) -> int:
    """``antalate bridge CONFIG``: run until SIGINT/SIGTERM, then print what was forwarded."""
    from antalate_lcm.apps.bridge import Bridge, load_bridge_config

    config = load_bridge_config(config_path)
    bridge = Bridge(config)
    bridge.start()
    print(f"bridge {bridge.id} running: {' <-> '.join(bridge.names)}", flush=True)
    try:
        wait_for_stop(stop)
    finally:
        bridge.close()
    print(f"bridge {bridge.id} stopped: {bridge.stats()}", flush=True)
    return 0


def cmd_bridge(args: argparse.Namespace) -> int:
    return run_bridge(args.config)


# ------------------------------------------------------------------ antalate lab-ca
def make_lab_ca(out: Path, *, hosts: list[str], clients: list[str], days: int = 30) -> list[Path]:
    """A throw-away CA in ``out`` (``ca.pem``/``ca.key``), a router certificate for ``hosts`` (its
    addresses or names, as clients write them in ``connect=``) and one client certificate per name
    (``NAME.pem``/``NAME.key``, CN=NAME). The openssl CLI does the work. For a lab: the CA key sits
    beside what it signed; a fielded swarm's CA lives elsewhere."""
    import ipaddress

    out.mkdir(parents=True, exist_ok=True)

    def openssl(*args: str) -> None:
        try:
            subprocess.run(["openssl", *args], check=True, capture_output=True, text=True)
        except FileNotFoundError:
            raise AntalateError("antalate lab-ca needs the openssl command (apt install openssl)") from None
        except subprocess.CalledProcessError as exc:
            raise AntalateError(f"openssl {args[0]} failed: {exc.stderr.strip()[-300:]}") from None

    def key_and_csr(name: str, cn: str) -> tuple[Path, Path]:
        key, csr = out / f"{name}.key", out / f"{name}.csr"
        openssl(
            "req",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            str(key),
            "-out",
            str(csr),
            "-subj",
            f"/CN={cn}",
        )
        key.chmod(0o600)
        return key, csr

    def sign(name: str, csr: Path, ext: str) -> Path:
        cert, extfile = out / f"{name}.pem", out / f"{name}.ext"
        extfile.write_text(ext)
        openssl(
            "x509",
            "-req",
            "-in",
            str(csr),
            "-CA",
            str(out / "ca.pem"),
            "-CAkey",
            str(out / "ca.key"),
            "-CAcreateserial",
            "-out",
            str(cert),
            "-days",
            str(days),
            "-extfile",
            str(extfile),
        )
        csr.unlink()
        extfile.unlink()
        return cert

    ca_key = out / "ca.key"
    openssl(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        str(ca_key),
        "-out",
        str(out / "ca.pem"),
        "-days",
        str(days),
        "-subj",
        "/CN=antalate lab CA",
        "-addext",
        "basicConstraints=critical,CA:TRUE",
        "-addext",
        "keyUsage=critical,keyCertSign,cRLSign",
    )
    ca_key.chmod(0o600)
    written = [out / "ca.pem", ca_key]
    sans = []
    for h in hosts:
        try:
            ipaddress.ip_address(h)
            sans.append(f"IP:{h}")
        except ValueError:
            sans.append(f"DNS:{h}")
    _, csr = key_and_csr("router", hosts[0])
    written += [
        sign(
            "router",
            csr,
            f"subjectAltName = {', '.join(sans)}\nbasicConstraints = CA:FALSE\nextendedKeyUsage = serverAuth\n",
        ),
        out / "router.key",
    ]
    for name in clients:
        _, csr = key_and_csr(name, name)
        written += [
            sign(name, csr, "basicConstraints = CA:FALSE\nextendedKeyUsage = clientAuth\n"),
            out / f"{name}.key",
        ]
    return written


def cmd_lab_ca(args: argparse.Namespace) -> int:
    names = args.client or []
    bad = [n for n in names if not n or "/" in n or n in ("ca", "router") or n.startswith(".")]
    if bad:
        raise AntalateError(f"expected client names that are file names (not ca or router), not {bad}")
    written = make_lab_ca(Path(args.dir), hosts=args.host or ["127.0.0.1"], clients=names, days=args.days)
    for path in written:
        print(path)
    return 0


def router_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to listen on, repeatable (default {DEFAULT_LISTEN}; {DEFAULT_TLS_LISTEN} with --tls-cert)",
    )
    p.add_argument("--lease", type=int, metavar="MS", help="link lease in ms (default: the buses' 3000)")
    p.add_argument("--tls-cert", metavar="PEM", help="the router's TLS certificate (tls/ endpoints)")
    p.add_argument("--tls-key", metavar="PEM", help="its private key")
    p.add_argument(
        "--ca", metavar="PEM", help="mutual TLS: every client's certificate must be signed by this CA"
    )
    p.add_argument("--users", metavar="FILE", help="Zenoh user:password lines: a client must know one pair")
    p.add_argument(
        "--prefix",
        action="append",
        metavar="PREFIX",
        help=f"key prefix a client may use, repeatable (default {DEFAULT_PREFIX}; the zenoh:// URL's network)",
    )
    p.add_argument("--plain", action="store_true", help="allow tcp/ endpoints beside TLS (unencrypted)")


def bridge_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="bridge config (TOML: [buses] and [bridge])")


def lab_ca_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", help="where to write ca.pem, router.pem, NAME.pem and their keys")
    p.add_argument(
        "--host",
        action="append",
        metavar="ADDRESS",
        help="the router's address or name as clients connect to it, repeatable (default 127.0.0.1)",
    )
    p.add_argument(
        "--client", action="append", metavar="NAME", help="a client certificate (a site), repeatable"
    )
    p.add_argument("--days", type=int, default=30, help="validity in days (default 30)")
