"""The ``antalate`` command. Each subcommand lives in the module that owns its job; this file only
parses arguments, sets up logging and turns antalate's own errors into one clear line."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence

from antalate_lcm.errors import AntalateError

Command = Callable[[argparse.Namespace], int]


def _setup_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )


def _cmd_spy(args: argparse.Namespace) -> int:
    from antalate_lcm.config import load_config
    from antalate_lcm.spy import run_spy

    config = load_config(args.config)
    url = config.buses.get(args.bus) if args.bus else config.buses.get(config.topics.default_bus)
    if url is None:
        raise AntalateError(
            f"no bus named {args.bus!r} in {config.source}; declared: {', '.join(config.buses)}"
        )
    if url.startswith("zenoh://"):
        from antalate_lcm.lcm_url import ZENOH_NOT_LCM

        raise AntalateError(f"cannot spy on {url}: {ZENOH_NOT_LCM}")
    return run_spy(url)


def _cmd_types(args: argparse.Namespace) -> int:
    from antalate_lcm.types_cmd import run

    return run(args.lang, args.out)


def _cmd_keygen(args: argparse.Namespace) -> int:
    """Print a new random swarm key (docs/security.md: generating and rotating keys)."""
    from antalate_lcm.security import generate_key

    print(generate_key())
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="antalate", description="Multi-agent UAV autonomy over LCM.")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR (default INFO)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("spy", help="start lcm-spy with every antalate type on the classpath")
    p.add_argument("config", nargs="?", help="config file (default: the embedded defaults)")
    p.add_argument("--bus", help="bus name from the config (default: the default bus)")
    p.set_defaults(func=_cmd_spy)

    from antalate_lcm.types_cmd import LANGUAGES

    p = sub.add_parser("types", help="write the message bindings for nodes in other languages (lcm-gen)")
    p.add_argument(
        "--lang", required=True, choices=LANGUAGES, help="target language, or lcm for the .lcm files"
    )
    p.add_argument("--out", required=True, help="folder to write into (created if missing)")
    p.set_defaults(func=_cmd_types)

    p = sub.add_parser(
        "keygen", help="print a new random swarm key for [security] swarm_key (docs/security.md)"
    )
    p.set_defaults(func=_cmd_keygen)

    for register in _registrars():
        register(sub)
    from operator_tui import web  # after the runtime's registrar: it adds --web to ``tui``

    web.register(sub)
    return parser


def _registrars() -> list[Callable[[argparse._SubParsersAction[argparse.ArgumentParser]], None]]:
    """Subcommands registered by the modules that implement them (imported lazily to start fast)."""
    from antalate_lcm import foxglove_server, gcs, mcap_record
    from antalate_lcm.runtime import commands, experiment, replay, router, scaffold, sweep
    from antalate_lcm.station import cli as station_cli

    return [
        commands.register,
        station_cli.register,
        router.register,
        experiment.register,
        replay.register,
        sweep.register,
        scaffold.register,
        mcap_record.register,
        foxglove_server.register,
        gcs.register,
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args.log_level)
    func: Command = args.func
    try:
        return func(args)
    except AntalateError as exc:
        print(f"antalate: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
