"""Ground stations see the swarm: ``antalate mavlink-gcs`` (docs/tools.md). ``view`` is the pure
mapping between agents and MAVLink vehicles, ``server`` the node, the UDP link and the command; this
module only holds the subcommand's arguments and handler (pymavlink is imported when it runs, not at every start)."""

from __future__ import annotations

import argparse

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 14551  # QGroundControl listens on 14550 itself; this is the one it connects to


def cmd_mavlink_gcs(args: argparse.Namespace) -> int:
    from antalate_lcm.apps.gcs.server import serve
    from antalate_lcm.core.config import load_config

    config = load_config(args.config)
    endpoint = f"udpout:{args.gcs}" if args.gcs else f"udpin:{args.host}:{args.port}"
    return serve(
        config,
        endpoint=endpoint,
        commands=args.commands,
        no_auth=args.no_auth,
        sysid_base=args.sysid_base,
        hide_autopilots=frozenset(args.hide_autopilot or ()),
    )


def mavlink_gcs_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="config with the bus (and [security] swarm_key for --commands)")
    p.add_argument(
        "--host", default=DEFAULT_HOST, help=f"address a ground station connects to (default {DEFAULT_HOST})"
    )
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"UDP port it connects to (default {DEFAULT_PORT})"
    )
    p.add_argument(
        "--gcs",
        metavar="HOST:PORT",
        help="send to a ground station listening there instead (QGroundControl: 127.0.0.1:14550)",
    )
    p.add_argument(
        "--sysid-base", type=int, default=101, help="system id of the first agent heard (default 101)"
    )
    p.add_argument(
        "--hide-autopilot",
        action="append",
        metavar="NAME",
        help="do not present agents flying this adapter (e.g. mavlink: their own MAVLink reaches the GCS)",
    )
    p.add_argument(
        "--commands", action="store_true", help="map the GCS's TAKEOFF/LAND/RTL to signed operator commands"
    )
    p.add_argument(
        "--no-auth", action="store_true", help="allow an address beyond loopback (unsafe, docs/tools.md)"
    )
