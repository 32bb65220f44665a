"""Subcommands that run nodes: ``mc``, ``hlc``, ``bma``, ``agent``, ``demo`` (and more as they exist),
and the ones that record and look at a flight: ``log``, ``analyze``, ``plot`` (docs/logging.md).

Every command loads and validates its whole config (plugins included) before any node starts.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.config import Config, check_unique_agent_names, load_config
from antalate_lcm.core.node import Context, Node

if TYPE_CHECKING:  # the plan imports every adapter's registry: only the commands that run nodes need it
    from antalate_lcm.agent.plan import AgentPlan
    from antalate_lcm.apps.analysis import AnalysisOptions


def _run_single(args: argparse.Namespace, make: Callable[[AgentPlan, Context], list[Node]]) -> int:
    from antalate_lcm.runtime.agent import validate
    from antalate_lcm.runtime.launch import run_until_signal

    config = load_config(args.config)
    plan = validate(config)  # the node is built from what was checked
    context = Context.create(config)
    return run_until_signal(context, make(plan, context))


def cmd_mc(args: argparse.Namespace) -> int:
    from antalate_lcm.agent.mc.node import McNode

    return _run_single(args, lambda plan, ctx: [McNode(plan.config, ctx)])


def cmd_hlc(args: argparse.Namespace) -> int:
    from antalate_lcm.agent.hlc.node import HlcNode

    return _run_single(
        args, lambda plan, ctx: [HlcNode(plan.config, ctx, plan.adapter.build(ctx.executor.clock))]
    )


def cmd_osc(args: argparse.Namespace) -> int:
    from antalate_lcm.agent.osc import OscNode

    return _run_single(args, lambda plan, ctx: [OscNode(plan.config, ctx)])


def cmd_bma(args: argparse.Namespace) -> int:
    from antalate_lcm.agent.bma.node import BmaNode

    def make(plan: AgentPlan, ctx: Context) -> list[Node]:
        cfg = plan.config
        for bma in plan.bmas:
            if bma.config.name == args.name:
                return [BmaNode(cfg, ctx, bma.config, bma)]
        names = ", ".join(b.name for b in cfg.bma) or "none"
        raise AntalateError(f"no [[bma]] named {args.name!r} in {cfg.source}; declared: {names}")

    return _run_single(args, make)


def cmd_agent(args: argparse.Namespace) -> int:
    from antalate_lcm.runtime.agent import (
        agent_nodes,
        default_processes,
        parse_shard,
        run_processes,
        shard,
        shared_buses,
        swarm_configs,
        validate,
    )
    from antalate_lcm.runtime.launch import run_until_signal

    configs: list[Config] = []
    for path in args.config:
        configs.extend(swarm_configs(load_config(path), args.agents, spacing=args.spacing))
    check_unique_agent_names(configs, agents=args.agents)  # names the file and agent.name
    plans = {id(cfg): validate(cfg) for cfg in configs}  # plugins resolved once, built from below
    processes = args.processes or default_processes(len(configs))
    if args.shard:
        configs = shard(configs, *parse_shard(args.shard))
    elif processes > 1:  # same channels, agents spread over processes (one loop, one core each)
        from antalate_lcm.agent.bma.plan import check_peer_buses

        for cfg in configs:  # before any process starts: one line naming the key, not a split swarm
            check_peer_buses(cfg, whole_swarm=False, plans=plans[id(cfg)].bmas)
        argv = [
            sys.executable,
            "-m",
            "antalate_lcm.cli",
            "--log-level",
            args.log_level,
            "agent",
            *args.config,
        ]
        argv += ["--agents", str(args.agents), "--spacing", str(args.spacing)]
        return run_processes(lambda i, n: [*argv, "--shard", f"{i}/{n}"], min(processes, len(configs)))
    if args.sim_clock:  # antalate run --speed --processes P: this shard on the run's clock
        context, release = _on_shared_clock(args, shared_buses(configs))
    else:
        # Internal topics between this process's nodes in memory: a spoofed LAN datagram never reaches them.
        context, release = Context.in_process(shared_buses(configs), whole_swarm=not args.shard), None
    nodes = [node for cfg in configs for node in agent_nodes(cfg, context, plans[id(cfg)])]
    if args.broadcast_reception is None and args.faults is None:
        return run_until_signal(context, nodes, started_all=release)
    from antalate_lcm.runtime.faults import broadcast_report, lossy_broadcasts

    if args.faults is not None:  # antalate run's [[fault]]s, injected into this process's agents
        from antalate_lcm.runtime.fault_processes import shard_faults
        from antalate_lcm.runtime.script import Script

        script = Script.model_validate_json(args.faults)
        name = "faults-" + (args.shard or "0/1").replace("/", "of")
        injector = shard_faults(configs, context, nodes, script, bus=args.fault_bus, name=name)
        gate = injector.gate
        nodes.append(injector)
    else:
        gate = lossy_broadcasts(nodes, args.broadcast_reception, args.seed)
    code = run_until_signal(context, nodes, started_all=release)
    for line in broadcast_report(gate):
        print(line, file=sys.stderr, flush=True)
    return code


def _on_shared_clock(args: argparse.Namespace, buses: dict[str, str]) -> tuple[Context, Callable[[], None]]:
    """The context of an agent process of ``antalate run --speed --processes P``: its loop on
    simulated time, joined to the run's clock (runtime/time_coordinator.py), held until every node
    of the process has started; and what releases it then."""
    from antalate_lcm.core.executor import Executor
    from antalate_lcm.core.node import INPROC_BUS
    from antalate_lcm.core.simclock import SimClock
    from antalate_lcm.runtime.agent import parse_shard
    from antalate_lcm.runtime.time_coordinator import SimulatedBuses, join, simulated_buses

    if not args.shard:
        raise AntalateError("--sim-clock is for the agent processes of `antalate run` (with --shard)")
    clock = SimClock(held=True)
    simulated, crossing = simulated_buses(buses)
    # As Context.in_process, on a bus that notes what the nodes subscribe to on the crossing buses.
    bus = SimulatedBuses({**simulated, INPROC_BUS: "memq://"}, crossing)
    context = Context(bus, Executor(sim=clock), inproc_bus=INPROC_BUS, seed=args.seed)
    index, _count = parse_shard(args.shard)
    join(args.sim_clock, index + 1, clock, bus, context.executor, crossing)
    return context, lambda: context.executor.call_soon(clock.release)


def cmd_demo(args: argparse.Namespace) -> int:
    from antalate_lcm.runtime import demo

    direction = (args.azimuth, args.speed) if args.azimuth is not None else None
    if args.headless:
        return demo.run_headless(args.agents, mission_time=args.mission_time, direction=direction)
    from antalate_lcm.runtime.interactive import run_interactive

    return run_interactive(args.agents)


def cmd_analyze(args: argparse.Namespace) -> int:
    import json

    from antalate_lcm.apps.analysis import analyze_log, format_summary

    result = analyze_log(args.log, **_analysis_options(args))
    if args.json:
        print(json.dumps(result.to_json(tracks=args.tracks), indent=1))
    else:
        print(format_summary(result))
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from antalate_lcm.apps.analysis import format_summary, plot_log

    path, result = plot_log(args.log, args.output, goals=args.goal or (), **_analysis_options(args))
    if not args.quiet:
        print(format_summary(result))
    print(f"wrote {path}")
    return 0


def cmd_log(args: argparse.Namespace) -> int:
    """``lcm-logger`` on a bus of the config: the stock tool, so the log replays with ``lcm-logplayer``.

    This process *becomes* lcm-logger (exec), so Ctrl-C or SIGTERM reach the logger itself and it
    closes the file cleanly; the ``lcm-logger`` on PATH is a Python wrapper that would not pass a
    SIGTERM on.
    """
    import time

    from antalate_lcm.transports import open_lcm

    config = load_config(args.config)
    bus = config.watched_bus(args.bus)
    url = config.bus_url(bus)
    open_lcm(url)  # a missing multicast route is reported with the fix, not as LCM's one-liner
    out = args.output or time.strftime("antalate-%Y%m%d-%H%M%S.lcm")
    if out.endswith(".mcap"):
        from antalate_lcm.apps.mcap_record import record

        return record(url, out, channel=args.channel, raw=args.raw, force=args.force)
    if args.raw:
        raise AntalateError("--raw is for an MCAP file (-o NAME.mcap): an LCM log keeps the bytes anyway")
    if os.path.exists(out) and not args.force:
        raise AntalateError(f"{out} exists: pass --force to overwrite it, or -o another file")
    logger = native_lcm_tool("lcm-logger")
    argv = [logger, f"--lcm-url={url}", f"--channel={args.channel}", "--force", out]
    print(f"logging bus {bus!r} ({url}) to {out}; Ctrl-C stops", flush=True)
    os.execv(logger, argv)
    return 0  # pragma: no cover - execv does not return


def native_lcm_tool(name: str) -> str:
    """The compiled LCM tool the ``lcm`` wheel ships (its PATH entry is a Python wrapper around it)."""
    from pathlib import Path

    import lcm

    from antalate_lcm.tools.codegen import lcm_tool

    native = Path(lcm.__file__).resolve().parent.parent / "bin" / name
    if native.is_file() and os.access(native, os.X_OK):
        return str(native)
    try:
        return lcm_tool(name)
    except FileNotFoundError as exc:
        raise AntalateError(str(exc)) from None


def positive_number(not_a_number: str, not_positive: str) -> Callable[[str], float]:
    """An argparse ``type``: a finite number > 0 (NaN and infinity are refused: a period, a radius or
    a timeout must be one), each refusal in the words given, followed by ``, got 'TEXT'``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{not_a_number}, got {text!r}") from None
        if not 0 < value < math.inf:
            raise argparse.ArgumentTypeError(f"{not_positive}, got {text!r}")
        return value

    return parse


_positive = positive_number("expected a number", "expected a positive finite number")


def _analysis_options(args: argparse.Namespace) -> AnalysisOptions:
    """The keywords of ``analyze_log`` from the options of :func:`_add_analysis_options`."""
    return {
        "azimuth": args.azimuth,
        "bin_s": args.bin,
        "max_age": args.max_age,
        "step": args.step,
        "range_m": args.range,
        "min_speed": args.min_speed,
        "radius_below": args.radius_below,
        "radius_above": args.radius_above,
        "safety": _safety_limits(args),
    }


def _safety_limits(args: argparse.Namespace) -> Any:
    """The `SafetyLimits` of ``--safety CONFIG`` and ``--radius``/``--vertical``/``--margin``/``--near-miss``
    (None when neither a config nor a radius is given: no safety section)."""
    from antalate_lcm.agent.hlc.safety import MEASURED_MARGIN, filter_params
    from antalate_lcm.apps.analysis import SafetyLimits

    radius, vertical, margin = args.radius, args.vertical, args.margin
    fence, origin = None, None
    if args.safety is not None:
        config = load_config(args.safety)
        sep = filter_params(config).separation
        radius = radius if radius is not None else sep.radius
        vertical = vertical if vertical is not None else sep.vertical
        if margin is None:
            margin = MEASURED_MARGIN.get(config.hlc.autopilot, 0.0)
        s = config.safety
        if s.origin:
            origin = (s.origin[0], s.origin[1])
        elif s.fence is not None and s.fence.polygon_wgs84:
            first = s.fence.polygon_wgs84[0]
            origin = (first[0], first[1])  # any point will do as the frame of a WGS84 fence
        if s.fence is not None and origin is not None:
            fence = s.fence.geofence(origin)
    if radius is None:
        for flag in ("vertical", "margin", "near_miss"):
            if getattr(args, flag) is not None:
                raise AntalateError(f"--{flag.replace('_', '-')} needs --radius or --safety CONFIG")
        return None
    return SafetyLimits(radius, vertical, margin or 0.0, args.near_miss, fence, origin)


def _add_analysis_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="LCM log or MCAP file (lcm-logger, antalate log, antalate export)")
    p.add_argument(
        "--azimuth",
        type=float,
        help="compare the drift with this direction (deg) instead of the direction commands in the log",
    )
    p.add_argument("--bin", type=_positive, default=1.0, help="cohesion sampling period, s (default 1)")
    p.add_argument(
        "--max-age",
        type=_positive,
        default=2.0,
        help="s after which an agent's last position no longer counts (default 2)",
    )
    p.add_argument(
        "--step", type=_positive, default=0.1, help="sampling step of the per-phase metrics, s (default 0.1)"
    )
    p.add_argument(
        "--range",
        type=_positive,
        default=10.0,
        help="range of the proximity graph (connectivity), m (default 10)",
    )
    p.add_argument(
        "--min-speed",
        type=_positive,
        default=0.2,
        help="m/s below which an agent has no heading for the polarisation (default 0.2)",
    )
    p.add_argument(
        "--radius-below",
        type=_positive,
        metavar="M",
        help="report when the radius first falls below M metres",
    )
    p.add_argument(
        "--radius-above",
        type=_positive,
        metavar="M",
        help="report when the radius first rises above M metres",
    )
    p.add_argument(
        "--safety",
        metavar="CONFIG",
        help="check separation, near-misses and the fence against this agent config's [safety] (docs/safety.md)",
    )
    p.add_argument(
        "--radius", type=_positive, metavar="M", help="separation radius, m (overrides --safety's)"
    )
    p.add_argument(
        "--vertical", type=_positive, metavar="M", help="separation half-height, m (default: 3-D distance)"
    )
    p.add_argument(
        "--margin",
        type=float,
        metavar="M",
        help="m below the radius still within the documented margin (default: the vehicle's, docs/safety.md)",
    )
    p.add_argument(
        "--near-miss",
        type=_positive,
        metavar="M",
        help="encounters closer than M m are near-misses (default: the radius)",
    )


def node_arguments(p: argparse.ArgumentParser) -> None:
    """``mc``, ``hlc`` and ``osc``: one node of one agent."""
    p.add_argument("config", help="agent config file (TOML)")


def bma_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="agent config file (TOML)")
    p.add_argument("--name", required=True, help="the [[bma]] name in the config")


def agent_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="+", help="agent config file(s): one per vehicle")
    p.add_argument("--agents", type=int, default=1, help="N simulated agents from each config (sim only)")
    p.add_argument("--spacing", type=float, default=8.0, help="metres between simulated homes (default 8)")
    p.add_argument(
        "--processes",
        type=int,
        help="spread the agents over P processes (default: one per core from 500 agents)",
    )
    p.add_argument("--shard", help=argparse.SUPPRESS)  # INDEX/COUNT: one of those processes
    # antalate run's [broadcast] reception and seed, for the agents of one of its processes
    p.add_argument("--broadcast-reception", type=float, help=argparse.SUPPRESS)
    p.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    # ... and its script (JSON) when it injects faults, with the bus their records go to
    p.add_argument("--faults", help=argparse.SUPPRESS)
    p.add_argument("--fault-bus", default="lan", help=argparse.SUPPRESS)
    # the socket of antalate run's simulated clock, shared by its processes (time_coordinator)
    p.add_argument("--sim-clock", help=argparse.SUPPRESS)


def demo_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--agents", type=int, default=5, help="number of simulated agents (default 5)")
    p.add_argument(
        "--headless", action="store_true", help="no console: a scripted operator flies one mission"
    )
    p.add_argument(
        "--mission-time", type=float, default=20.0, help="seconds in MISSION before RTL (headless)"
    )
    p.add_argument("--azimuth", type=float, help="direction command during the mission, deg (headless)")
    p.add_argument("--speed", type=float, default=1.0, help="direction command speed, m/s (headless)")


def analyze_arguments(p: argparse.ArgumentParser) -> None:
    _add_analysis_options(p)
    p.add_argument("--json", action="store_true", help="print every number as JSON instead of the summary")
    p.add_argument("--tracks", action="store_true", help="with --json: every agent's trajectory too")


def plot_arguments(p: argparse.ArgumentParser) -> None:
    _add_analysis_options(p)
    p.add_argument("-o", "--output", help="PNG file (default: the log's name with .png)")
    p.add_argument("-q", "--quiet", action="store_true", help="do not print the analysis summary")
    p.add_argument(
        "--goal",
        type=_positive,
        action="append",
        metavar="M",
        help="draw a goal radius of M metres on the cohesion panel (repeatable; none by default)",
    )


def log_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="config file (default: the embedded defaults)")
    p.add_argument(
        "-o", "--output", help="log file; NAME.mcap records MCAP (default: antalate-YYYYmmdd-HHMMSS.lcm)"
    )
    p.add_argument(
        "--bus", help="bus name from the config (default: 'lan' if declared, else the default bus)"
    )
    p.add_argument("--channel", default=".*", help="channel regex to record (default: every channel)")
    p.add_argument("-f", "--force", action="store_true", help="overwrite the log file if it exists")
    p.add_argument("--raw", action="store_true", help="MCAP: keep each message's LCM bytes too (raw/CHANNEL)")
