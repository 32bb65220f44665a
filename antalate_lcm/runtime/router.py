"""``antalate router``: a Zenoh router in its own process, for the sites' bridges and agents to reach.

It is eclipse-zenoh's router mode, with what antalate's buses assume: no multicast scouting (a
router at a site must not pull in whatever Zenoh nodes answer on its LAN) and the same short link
lease as the buses (:data:`antalate_lcm.zenoh_bus.DEFAULT_LEASE_MS`), so a cut link is noticed
and re-made quickly. For a production router (access control, TLS, storage, the REST plugin) run
``zenohd`` with a config file instead; nothing in antalate depends on which one answers.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
from typing import TYPE_CHECKING

from antalate_lcm.errors import AntalateError
from antalate_lcm.lcm_url import zenoh_endpoints_problem
from antalate_lcm.runtime.launch import wait_for_stop

if TYPE_CHECKING:  # the zenoh extra is optional: imported where used
    import zenoh

log = logging.getLogger("antalate.router")

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"


def router_config(listen: list[str], lease_ms: int) -> zenoh.Config:
    import zenoh

    config: zenoh.Config = zenoh.Config()  # zenoh's stub returns typing.Self, Any before 3.11
    config.insert_json5("mode", json.dumps("router"))
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tx/lease", str(lease_ms))
    return config


def run_router(listen: list[str], *, lease_ms: int, stop: threading.Event | None = None) -> int:
    """Listen on ``listen`` until SIGINT/SIGTERM (or ``stop``)."""
    for endpoint in listen:
        problem = zenoh_endpoints_problem("--listen", endpoint)
        if problem:
            raise AntalateError(f"expected {problem}")
    try:
        import zenoh
    except ImportError:
        raise AntalateError("the Zenoh library is not installed: pip install 'antalate[zenoh]'") from None
    try:
        session = zenoh.open(router_config(listen, lease_ms))
    except zenoh.ZError as exc:
        raise AntalateError(f"the Zenoh router cannot listen on {', '.join(listen)}: {exc}") from None
    print(f"zenoh router {session.zid()} listening on {', '.join(listen)}", flush=True)
    try:
        wait_for_stop(stop)
    finally:
        session.close()
    return 0


def _cmd_router(args: argparse.Namespace) -> int:
    from antalate_lcm.zenoh_bus import DEFAULT_LEASE_MS

    return run_router(args.listen or [DEFAULT_LISTEN], lease_ms=args.lease or DEFAULT_LEASE_MS)


def run_bridge(config_path: str, *, stop: threading.Event | None = None) -> int:
    """``antalate bridge CONFIG``: run until SIGINT/SIGTERM, then print what was forwarded."""
    from antalate_lcm.bridge import Bridge, load_bridge_config

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


def _cmd_bridge(args: argparse.Namespace) -> int:
    return run_bridge(args.config)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``router`` and ``bridge`` to the ``antalate`` parser (docs/wan.md)."""
    p = sub.add_parser("router", help="a Zenoh router for zenoh:// buses across networks (docs/wan.md)")
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to listen on, repeatable (default {DEFAULT_LISTEN})",
    )
    p.add_argument("--lease", type=int, metavar="MS", help="link lease in ms (default: the buses' 3000)")
    p.set_defaults(func=_cmd_router)

    p = sub.add_parser(
        "bridge", help="forward channels between two buses, e.g. a LAN and Zenoh (docs/wan.md)"
    )
    p.add_argument("config", help="bridge config (TOML: [buses] and [bridge])")
    p.set_defaults(func=_cmd_bridge)
