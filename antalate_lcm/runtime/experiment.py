"""``antalate run CONFIG``: one command for one experiment (docs/experiments.md).

It flies ``CONFIG`` with N simulated agents (``--agents``, homes on a grid as ``antalate agent``
makes them), in this process or spread over ``--processes P`` (``antalate agent --shard`` children,
exactly what ``antalate agent --processes`` runs), records one bus to an LCM log (``-o``) from
this process, and prints the swarm metrics of ``antalate analyze`` at the end.

With ``--headless`` a :class:`ScriptedOperator` flies the script (take-off, direction commands at
given times, mission duration, RTL) and the exit status says whether every agent came back to
STANDBY; without it the operator console flies, and the metrics follow when it quits.

Everything is checked before anything flies (:func:`prepare`, in
:mod:`antalate_lcm.runtime.experiment_spec` with the :class:`Experiment` it checks): the config and
its plugins, the script, and that this process can hear and command agents that run in other
processes (the operator's topics on buses whose transport crosses processes).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config, load_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.core.simclock import SimClock
from antalate_lcm.runtime.agent import agent_nodes, run_processes, shared_buses
from antalate_lcm.runtime.experiment_spec import (
    Experiment,
    check_interference,
    check_reach,
    check_simulated,
    default_log_path,
    parse_speed,
    parse_stall,
    prepare,
    record_bus,
)
from antalate_lcm.runtime.launch import run_until_signal
from antalate_lcm.runtime.recorder import LogRecorder
from antalate_lcm.runtime.script import Script, load_script
from antalate_lcm.runtime.scripted_operator import DirectionAt, Phase, ScriptedOperator
from antalate_lcm.runtime.time_coordinator import (
    DEFAULT_STALL,
    SimulatedBuses,
    TimeCoordinator,
    simulated_buses,
)
from antalate_lcm.transports import transport_for

if TYPE_CHECKING:
    from antalate_lcm.apps.analysis import Analysis
    from antalate_lcm.runtime.faults import FaultInjector


def _interfere(
    configs: list[Config], context: Context, nodes: list[Node], script: Script, bus: str, processes: int = 1
) -> FaultInjector | None:
    """Put the script's faults and broadcast losses between the agents' nodes and the bus."""
    if not script.interferes:
        return None
    if processes > 1:  # the agent processes inject them: runtime/fault_processes.py
        from antalate_lcm.runtime.fault_processes import FaultRelay
        from antalate_lcm.runtime.faults import FaultGate

        settings = NodeSettings.from_config(configs[0], agent="faults")
        return FaultRelay(settings, context, script=script, gate=FaultGate(), bus=bus, excuse=lambda _a: None)
    from antalate_lcm.agent.hlc.node import HlcNode
    from antalate_lcm.runtime.faults import FaultInjector, agents_gate

    vehicles = {n.agent: n.adapter for n in nodes if isinstance(n, HlcNode)}
    return FaultInjector(
        NodeSettings.from_config(configs[0], agent="faults"),
        context,
        script=script,
        agents=[c.agent.name for c in configs],
        gate=agents_gate([n for n in nodes if not isinstance(n, LogRecorder)], script),
        bus=bus,
        mission_start=lambda: None,
        excuse=lambda _agent: None,
        vehicles=vehicles,
    )


def _operator(configs: list[Config], context: Context, script: Script) -> ScriptedOperator:
    return ScriptedOperator(
        NodeSettings.from_config(configs[0], agent="operator"),
        context,
        expected_agents=len(configs),
        mission_time=script.mission_time,
        altitude=script.altitude,
        directions=[DirectionAt(d.at, d.azimuth, d.speed, d.active) for d in script.direction],
        timeout=script.mission_time + script.timeout,
    )


def _child_argv(exp: Experiment, clock: str | None = None) -> Callable[[int, int], list[str]]:
    argv = [sys.executable, "-m", "antalate_lcm.cli", "--log-level", exp.log_level, "agent", exp.config_path]
    argv += ["--agents", str(exp.agents), "--spacing", str(exp.spacing)]
    script = exp.script or load_script(None)
    if exp.seed is not None:
        script = script.model_copy(update={"seed": exp.seed})
    if script.broadcast.reception < 1.0:  # each process loses broadcasts at its own agents
        argv += ["--broadcast-reception", repr(script.broadcast.reception)]
    if script.broadcast.reception < 1.0 or clock is not None:  # ... and its timers' phases with it
        argv += ["--seed", str(script.seed)]
    if clock is not None:  # the shared simulated clock (time_coordinator)
        argv += ["--sim-clock", clock]
    if script.fault:  # ... and injects the faults into them (runtime/fault_processes.py)
        bus = record_bus(load_config(exp.config_path), exp.bus)
        argv += ["--faults", script.model_dump_json(), "--fault-bus", bus]
    return lambda i, n: [*argv, "--shard", f"{i}/{n}"]


@dataclass
class Outcome:
    """What an experiment gives: the exit status, the flight and its measure."""

    code: int
    log: str
    bus: str
    #: Messages the recorder wrote.
    messages: int
    #: The scripted operator's report (each agent's MC timeline, OK/FAILED and why); "" with the console.
    report: str = ""
    #: Each agent's MC states as the operator saw them: (s since the operator started, state name).
    timelines: dict[str, list[tuple[float, str]]] = field(default_factory=dict)
    #: The metrics of the recorded log (None when it holds nothing to analyse: then ``problem`` says why).
    analysis: Analysis | None = None
    problem: str = ""
    #: With the console: the file that holds the nodes' log lines.
    node_log: str = ""
    #: Real seconds the flight took (nodes started to nodes stopped).
    real_s: float = 0.0
    #: Simulated seconds it covered (``--speed``), None on the wall clock.
    simulated_s: float | None = None
    #: CPU seconds this process spent meanwhile (all its threads).
    cpu_s: float = 0.0
    #: Rounds of the processes' shared clock (``--speed`` with ``--processes``): deliveries and
    #: advances, each a message to every process and its answer; None in one process.
    clock_rounds: int | None = None

    def text(self) -> str:
        """What ``antalate run`` prints."""
        lines = [self.report] if self.report else []
        if self.node_log:
            lines.append(f"the nodes' log lines are in {self.node_log}")
        lines.append(f"log: {self.log} ({self.messages} messages on bus {self.bus!r})")
        if self.simulated_s is not None:
            rounds = "" if self.clock_rounds is None else f"; {self.clock_rounds} rounds of the shared clock"
            lines.append(
                f"simulated time: {self.simulated_s:.1f} s in {self.real_s:.1f} s real "
                f"({self.simulated_s / max(self.real_s, 1e-9):.1f}x real time{rounds})"
            )
        if self.analysis is not None:
            from antalate_lcm.apps.analysis import format_summary

            lines.append(format_summary(self.analysis))
        else:
            lines.append(f"no metrics: {self.problem}")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        """What ``antalate run --json`` prints: the same, as plain JSON types."""
        return {
            "ok": self.code == 0,
            "code": self.code,
            "log": self.log,
            "bus": self.bus,
            "messages": self.messages,
            "report": self.report or None,
            "timelines": {a: [{"t": t, "state": s} for t, s in tl] for a, tl in self.timelines.items()},
            "node_log": self.node_log or None,
            "analysis": self.analysis.to_json() if self.analysis is not None else None,
            "problem": self.problem or None,
            "real_s": self.real_s,
            "simulated_s": self.simulated_s,
            "cpu_s": self.cpu_s,
        }


def run(exp: Experiment) -> Outcome:
    """Fly the experiment, then measure its log (every check first: :func:`prepare`)."""
    script = exp.script or load_script(None)
    if exp.seed is not None:
        script = script.model_copy(update={"seed": exp.seed})
    configs, bus, out = prepare(exp)
    processes = min(exp.processes, len(configs))
    buses = shared_buses(configs)
    # Several processes on simulated time: one clock for all, served from here (time_coordinator).
    coordinator = (
        TimeCoordinator(processes + 1, exp.speed, exp.stall_timeout)
        if exp.speed is not None and processes > 1
        else None
    )
    clock = None if exp.speed is None else SimClock(math.inf if coordinator else exp.speed, held=True)
    crossing: list[str] = []
    if coordinator is not None:
        buses, crossing = simulated_buses(buses)
    elif clock is not None:
        # Simulated agents in one process on simulated time: a datagram through the kernel would
        # come back at a real moment, not a simulated one, so every bus stays in the process.
        buses = {
            name: "memq://" if transport_for(url).crosses_processes else url for name, url in buses.items()
        }
    # One process: every agent's internal topics in memory, as `antalate agent` runs them, and the
    # whole swarm here (a peer behavior may hear its peers on memq://). Several: this process only
    # commands and records, on the configured buses.
    context = (
        Context.in_process(buses, whole_swarm=True, executor=Executor(sim=clock))
        if processes == 1
        else Context(SimulatedBuses(buses, crossing) if coordinator else Buses(buses), Executor(sim=clock))
    )
    if clock is not None or exp.seed is not None:
        context.seed = script.seed
    if coordinator is not None and clock is not None and isinstance(context.buses, SimulatedBuses):
        coordinator.serve(clock, context.buses, context.executor, crossing)
    recorder = LogRecorder(NodeSettings.from_config(configs[0], agent="recorder"), context, bus=bus, path=out)
    nodes: list[Node] = [recorder]
    if processes == 1:
        nodes += [node for cfg in configs for node in agent_nodes(cfg, context)]
    injector = _interfere(configs, context, nodes, script, bus, processes)
    if injector is not None:
        nodes.append(injector)
    # With the console, every log line goes to a file: they would tear the console's screen.
    node_log = "" if exp.headless else _temp_log()
    clock_address = coordinator.address if coordinator is not None else None
    children = _AgentProcesses(exp, processes, node_log, clock_address) if processes > 1 else None
    outcome = Outcome(1, out, bus, 0, node_log=node_log)
    started, cpu = time.monotonic(), time.process_time()
    try:
        if exp.headless:
            _fly_scripted(configs, context, nodes, script, children, outcome, injector, clock, coordinator)
        else:
            outcome.code = _run_console(configs[0], context, nodes, node_log)
    finally:
        if coordinator is not None:
            coordinator.finish()
        if children is not None:
            children.stop()
        if coordinator is not None:
            coordinator.close()
            outcome.clock_rounds = coordinator.rounds
    outcome.real_s, outcome.cpu_s = time.monotonic() - started, time.process_time() - cpu
    if clock is not None:
        outcome.simulated_s = clock.elapsed
        from antalate_lcm.runtime.replay import write_record

        write_record(exp, script, out)
    outcome.messages = recorder.events
    if injector is not None:
        outcome.report = "\n".join([outcome.report, *injector.report()]).strip()
    if exp.measure:
        _measure(outcome, script)
    else:
        outcome.problem = "not measured"
    return outcome


class _AgentProcesses:
    """The agents' processes (``antalate agent --shard``), supervised from a thread of this one."""

    def __init__(self, exp: Experiment, count: int, node_log: str, clock: str | None = None) -> None:
        self.done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._supervise, args=(exp, count, node_log, clock), name="agent-processes", daemon=True
        )
        self._thread.start()

    def _supervise(self, exp: Experiment, count: int, node_log: str, clock: str | None) -> None:
        try:
            if not node_log:
                run_processes(_child_argv(exp, clock), count, stop=self._stop)
            else:
                with open(node_log, "ab") as output:
                    run_processes(_child_argv(exp, clock), count, stop=self._stop, output=output)
        finally:
            self.done.set()

    def stop(self) -> None:
        """Stop every agent process (SIGINT, each stops its nodes in order) and wait for them."""
        self._stop.set()
        self._thread.join()


def _fly_scripted(
    configs: list[Config],
    context: Context,
    nodes: list[Node],
    script: Script,
    children: _AgentProcesses | None,
    outcome: Outcome,
    injector: FaultInjector | None = None,
    clock: SimClock | None = None,
    coordinator: TimeCoordinator | None = None,
) -> None:
    operator = _operator(configs, context, script)
    if injector is not None:
        operator.interference = injector.gate  # a link loss cuts the operator's side too
        injector.mission_start = lambda: operator.mission_started
        injector.excuse = operator.excused.add
        operator.on_finish.append(injector.summarize)
    ended = children.done if children is not None else threading.Event()
    release = None
    if clock is not None:
        # Time stands still while the nodes start (from this thread, in batches) and once the
        # script has ended (the nodes stop from this thread): what is recorded never depends on
        # how fast this thread is.
        operator.on_finish.append(clock.hold)
        sim = clock

        def release() -> None:
            context.executor.call_soon(sim.release)

    # Set on the loop the moment the script ends (after the clock's hold): the stop does not wait
    # for the main thread's next look (up to 0.2 s: a tenth of a hundred agents' run at --speed max).
    finished = threading.Event()
    operator.on_finish.append(finished.set)
    run_until_signal(
        context,
        [*nodes, operator],
        stop_event=finished,
        poll=lambda: (
            operator.finished or ended.is_set() or (coordinator is not None and coordinator.lost.is_set())
        ),
        started_all=release,
    )
    outcome.code = 0 if operator.phase is Phase.DONE else 1
    if not operator.finished:
        if coordinator is not None and coordinator.failure:
            operator.reason = coordinator.failure
        elif ended.is_set():
            operator.reason = "an agent process ended before the experiment did"
        else:  # run_until_signal only returns early on SIGINT or SIGTERM
            operator.reason, outcome.code = "interrupted (SIGINT or SIGTERM)", 130
    outcome.report = operator.report()
    outcome.timelines = {
        name: [(t, state.name) for t, state in tl.entries] for name, tl in sorted(operator.timelines.items())
    }


def _temp_log() -> str:
    import tempfile

    fd, path = tempfile.mkstemp(prefix="antalate-run-", suffix=".log")
    os.close(fd)
    return path


def _run_console(config: Config, context: Context, nodes: list[Node], log_path: str) -> int:
    """The operator console in the foreground, the nodes on the executor behind it (as ``antalate demo``);
    the log lines go to ``log_path`` meanwhile."""
    from antalate_lcm.runtime.interactive import _log_to_file

    with _log_to_file(log_path):
        return _console(config, context, nodes)


def _console(config: Config, context: Context, nodes: list[Node]) -> int:
    from operator_tui.app import OperatorApp

    started: list[Node] = []
    try:
        context.buses.open()
        context.executor.start()
        for node in nodes:
            node.start()
            started.append(node)
        app = OperatorApp(config, context=context, name="operator")
        app.run()
        return app.return_code or 0
    finally:
        for node in reversed(started):
            with contextlib.suppress(Exception):
                node.stop()
        context.close()


def _measure(outcome: Outcome, script: Script) -> None:
    from antalate_lcm.apps.analysis import analyze_log

    options = script.analyze
    try:
        outcome.analysis = analyze_log(
            outcome.log,
            range_m=options.range_m,
            radius_below=options.radius_below,
            radius_above=options.radius_above,
        )
    except AntalateError as exc:  # a flight that never got going leaves a log with nothing to analyse
        outcome.problem = str(exc)


def cmd_run(args: argparse.Namespace) -> int:
    import json

    outcome = run(
        Experiment(
            config_path=args.config,
            agents=args.agents,
            processes=args.processes,
            spacing=args.spacing,
            script=load_script(args.script),
            script_source=args.script or "script",
            output=args.output,
            bus=args.bus,
            headless=args.headless,
            force=args.force,
            log_level=args.log_level,
            speed=args.speed,
            seed=args.seed,
            stall_timeout=args.stall_timeout,
        )
    )
    print(json.dumps(outcome.to_json(), indent=1) if args.json else outcome.text(), flush=True)
    return outcome.code


def run_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="agent config file (TOML), e.g. the one `antalate new behavior` wrote")
    p.add_argument(
        "--agents", type=int, default=1, metavar="N", help="N simulated agents from the config (default 1)"
    )
    p.add_argument(
        "--processes", type=int, default=1, metavar="P", help="spread the agents over P processes (default 1)"
    )
    p.add_argument(
        "--spacing", type=float, default=8.0, metavar="M", help="metres between simulated homes (default 8)"
    )
    p.add_argument(
        "--script", metavar="SCRIPT", help="experiment script (TOML; default: a 30 s mission, then RTL)"
    )
    p.add_argument(
        "-o", "--output", metavar="LOG", help="LCM log file (default: antalate-run-YYYYmmdd-HHMMSS.lcm)"
    )
    p.add_argument("--bus", help="bus to record (default: 'lan' if declared, else the default bus)")
    p.add_argument("-f", "--force", action="store_true", help="overwrite the log file if it exists")
    p.add_argument("--json", action="store_true", help="print the outcome and every metric as JSON")
    p.add_argument(
        "--headless", action="store_true", help="the script's operator flies (no console); for scripts and CI"
    )
    p.add_argument(
        "--speed",
        type=parse_speed,
        metavar="max|N",
        help="simulated time: as fast as this process computes (max) or at most N times real time",
    )
    p.add_argument(
        "--seed",
        type=int,
        metavar="S",
        help="the script's seed; with --speed the run (its log, byte for byte) is a function of "
        "config, script and S, and `antalate replay LOG` checks it",
    )
    p.add_argument(
        "--stall-timeout",
        type=parse_stall,
        default=DEFAULT_STALL,
        metavar="S",
        help="with --speed and --processes: an agent process silent for S real seconds is taken as "
        f"hung; the run stops with its name and it is killed (default {DEFAULT_STALL:g})",
    )


__all__ = [
    "Experiment",
    "Outcome",
    "check_interference",
    "check_reach",
    "check_simulated",
    "cmd_run",
    "default_log_path",
    "parse_speed",
    "parse_stall",
    "prepare",
    "record_bus",
    "run",
    "run_arguments",
]
