"""``python -m operator_tui [CONFIG]``: the console without the ``antalate`` CLI (same as ``antalate tui``)."""

from __future__ import annotations

import argparse
import sys

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.config import load_config
from operator_tui import run


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m operator_tui", description="antalate operator console")
    parser.add_argument("config", nargs="?", help="config file (default: the embedded defaults, LAN bus)")
    parser.add_argument(
        "--name", default="operator", help="the console's agent name on the bus (default operator)"
    )
    parser.add_argument(
        "--headless", type=float, metavar="SECONDS", help="run without a terminal for SECONDS"
    )
    args = parser.parse_args(argv)
    try:
        return run(load_config(args.config), name=args.name, headless_exit_after=args.headless)
    except AntalateError as exc:
        print(f"antalate tui: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
