"""``antalate tui``: its arguments and its handler, the terminal console and ``--web`` alike.

Both ways of opening the console are one subcommand, so their options are declared together here and
registered once from the table in ``antalate_lcm/cli.py``; nothing edits this parser afterwards.
"""

from __future__ import annotations

import argparse

from antalate_lcm.core.config import load_config
from operator_tui.web import DEFAULT_HOST, DEFAULT_PORT, serve


def tui_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="config with the LAN bus (default: the embedded defaults)")
    p.add_argument("--name", help="the console's own name on the bus (default: the config's agent name)")
    p.add_argument("--web", action="store_true", help="serve the console to a browser (textual-serve)")
    p.add_argument(
        "--host", default=DEFAULT_HOST, help=f"--web: address to listen on (default {DEFAULT_HOST})"
    )
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"--web: port (default {DEFAULT_PORT})")
    p.add_argument(
        "--keys", metavar="STATION_TOML", help="--web: sign in with the operator API keys of this file"
    )
    p.add_argument("--no-auth", action="store_true", help="--web: allow no sign-in beyond loopback (unsafe)")
    p.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help="--web: a host name the console answers to besides its listen address (repeatable); "
        "any other Host is refused (DNS rebinding)",
    )


def cmd_tui(args: argparse.Namespace) -> int:
    if args.web:
        return serve(
            args.config,
            name=args.name,
            host=args.host,
            port=args.port,
            keys_file=args.keys,
            no_auth=args.no_auth,
            allow_hosts=tuple(args.allow_host),
        )
    import operator_tui

    config = load_config(args.config)  # the swarm's buses, topics and key (None: the defaults')
    return operator_tui.run(config, name=args.name or (config.agent.name if args.config else "operator"))
