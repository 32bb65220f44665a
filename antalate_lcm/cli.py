"""The ``antalate`` command: every subcommand, in the order ``antalate --help`` lists them.

:func:`subcommands` is the one table of the command line. Each row names a subcommand, its one-line help,
the function that declares its arguments and the handler that runs it; both functions live next to each
other in the module that owns the job (``runtime/experiment.py`` for ``run``, ``operator_tui/cli.py``
for ``tui``...). A command is added by adding a row here and nowhere else: no module registers itself,
and none edits another's parser after it is built. This file also sets up logging and turns antalate's
own errors into one clear line.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.errors import AntalateError

Handler = Callable[[argparse.Namespace], int]


@dataclass(frozen=True)
class Subcommand:
    """One row of the table: ``antalate NAME``, what it does, how it is called and what runs it."""

    name: str
    help: str
    arguments: Callable[[argparse.ArgumentParser], None] | None
    run: Handler


def _cmd_keygen(args: argparse.Namespace) -> int:
    """Print a new random swarm key (docs/security.md: generating and rotating keys)."""
    from antalate_lcm.wire.security import generate_key

    print(generate_key())
    return 0


def subcommands() -> tuple[Subcommand, ...]:
    """The table. Its modules are imported here, not at the top, so ``import antalate_lcm.cli`` stays
    cheap for the tests and tools that only want :func:`main`."""
    from antalate_lcm.apps import foxglove_server, gcs, mcap_record, spy, types_cmd
    from antalate_lcm.runtime import cli as nodes
    from antalate_lcm.runtime import experiment, replay, router, scaffold, sweep
    from antalate_lcm.station import cli as station
    from operator_tui import cli as console

    return (
        # looking at a bus, and bindings for nodes in other languages
        Subcommand(
            "spy",
            "start lcm-spy with every antalate type on the classpath",
            spy.spy_arguments,
            spy.cmd_spy,
        ),
        Subcommand(
            "types",
            "write the message bindings for nodes in other languages (lcm-gen)",
            types_cmd.types_arguments,
            types_cmd.cmd_types,
        ),
        Subcommand(
            "keygen",
            "print a new random swarm key for [security] swarm_key (docs/security.md)",
            None,
            _cmd_keygen,
        ),
        # running nodes and agents (runtime/cli.py)
        Subcommand("mc", "run the Mission Control node of an agent", nodes.node_arguments, nodes.cmd_mc),
        Subcommand(
            "hlc",
            "run the High-Level Control node (and its vehicle adapter) of an agent",
            nodes.node_arguments,
            nodes.cmd_hlc,
        ),
        Subcommand(
            "osc",
            "run the Operator Station Client of an agent (needs [osc] server)",
            nodes.node_arguments,
            nodes.cmd_osc,
        ),
        Subcommand("bma", "run one Behavior Module Arbiter of an agent", nodes.bma_arguments, nodes.cmd_bma),
        Subcommand(
            "agent",
            "run every node of one or more agents in one process",
            nodes.agent_arguments,
            nodes.cmd_agent,
        ),
        # the operator console, in a terminal or (--web) a browser
        Subcommand(
            "tui",
            "the operator console (a Textual app on the LAN bus)",
            console.tui_arguments,
            console.cmd_tui,
        ),
        Subcommand(
            "demo",
            "fly a simulated swarm (the template application)",
            nodes.demo_arguments,
            nodes.cmd_demo,
        ),
        # recording a flight and looking at it (docs/logging.md)
        Subcommand(
            "analyze",
            "swarm metrics from an LCM log, per phase: radius, separation, polarisation, connectivity, drift",
            nodes.analyze_arguments,
            nodes.cmd_analyze,
        ),
        Subcommand(
            "plot",
            "PNG of trajectories, state timelines and cohesion from an LCM log",
            nodes.plot_arguments,
            nodes.cmd_plot,
        ),
        Subcommand(
            "log",
            "record a bus to an LCM log file (lcm-logger on the config's bus)",
            nodes.log_arguments,
            nodes.cmd_log,
        ),
        # the reference operator station and its client (station/cli.py)
        Subcommand(
            "station",
            "run the reference operator station (HTTP(S) + SQLite)",
            station.station_arguments,
            station.cmd_station,
        ),
        Subcommand(
            "station-key",
            "make an API key, or the station's registration key",
            station.station_key_arguments,
            station.cmd_station_key,
        ),
        Subcommand(
            "command",
            "send an operator command through a station (signed with the swarm key)",
            station.command_arguments,
            station.cmd_command,
        ),
        # buses across networks (docs/wan.md)
        Subcommand(
            "router",
            "a Zenoh router for zenoh:// buses across networks (docs/wan.md)",
            router.router_arguments,
            router.cmd_router,
        ),
        Subcommand(
            "bridge",
            "forward channels between two buses, e.g. a LAN and Zenoh (docs/wan.md)",
            router.bridge_arguments,
            router.cmd_bridge,
        ),
        Subcommand(
            "lab-ca",
            "a throw-away CA and certificates for a TLS router and its clients (docs/wan.md)",
            router.lab_ca_arguments,
            router.cmd_lab_ca,
        ),
        # experiments (docs/experiments.md)
        Subcommand(
            "run",
            "fly a config with N simulated agents and a scripted operator, record it, print the swarm metrics",
            experiment.run_arguments,
            experiment.cmd_run,
        ),
        Subcommand(
            "replay",
            "run a recorded `antalate run --speed` experiment again; report the first divergence",
            replay.replay_arguments,
            replay.cmd_replay,
        ),
        Subcommand(
            "sweep",
            "run `antalate run` over parameters and seeds in parallel; one table (CSV, JSON) of the metrics",
            sweep.sweep_arguments,
            sweep.cmd_sweep,
        ),
        Subcommand(
            "new",
            "write a new behavior package that installs and flies as generated",
            scaffold.new_arguments,
            scaffold.cmd_new,
        ),
        # other tools (docs/tools.md)
        Subcommand(
            "export",
            "convert an LCM log to MCAP (Foxglove, PlotJuggler): docs/tools.md",
            mcap_record.export_arguments,
            mcap_record.cmd_export,
        ),
        Subcommand(
            "foxglove",
            "serve the swarm live to Foxglove (WebSocket, read-only): docs/tools.md",
            foxglove_server.foxglove_arguments,
            foxglove_server.cmd_foxglove,
        ),
        Subcommand(
            "mavlink-gcs",
            "every agent as a MAVLink vehicle for QGroundControl/MAVProxy: docs/tools.md",
            gcs.mavlink_gcs_arguments,
            gcs.cmd_mavlink_gcs,
        ),
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="antalate", description="Multi-agent UAV autonomy over LCM.")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR (default INFO)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in subcommands():
        p = sub.add_parser(command.name, help=command.help)
        if command.arguments is not None:
            command.arguments(p)
        p.set_defaults(func=command.run)
    return parser


def _setup_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args.log_level)
    func: Handler = args.func
    try:
        return func(args)
    except AntalateError as exc:
        print(f"antalate: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
