"""How much faster than real time a simulated swarm flies on simulated time (``antalate run --speed max``),
beside the same flight on the wall clock.

For each N it flies the same experiment three times, each from a fresh process: N agents (MC + HLC +
sim + BMA with ``dovrat_swarm``, every bus in memory, the in-process recorder writing every
message), the default script's operator (take off, a direction at 5 s, a ``--mission`` s mission,
RTL), seed 1:

- ``--speed max`` in one process: the simulated seconds the flight covered, the real seconds it
  took, their ratio (the speed-up over real time; goal: >= 20x for 100 agents, >= 2x for 1,000 on
  one core), and the CPU seconds it used (simulated / CPU is the speed-up the process would get
  with a core to itself);
- ``--speed max --processes P`` (``--processes``, default 2; 1: not flown): the same over P agent
  processes and the operator's, on one simulated clock (runtime/time_coordinator.py), the CPU of
  all of them, and the rounds of the shared clock per simulated second (what it costs);
- the wall clock: the real seconds of the same flight and the share of a core it took (above 100 %
  the process cannot keep up: its timers run late, as ``benchmarks/agents.py`` shows).

Beside each, ``us/ag-s``: the CPU microseconds per agent and simulated (or, on the wall clock,
real) second. On the same machine at the same moment the two are what simulated time costs over
the agents' own work (its loop, timer grid and held start and stop): 2x real time for 1,000 agents
on one core needs 500 us per agent-second.

The metrics of ``antalate run`` are skipped (their analysis is not the flight). The machine is
shared, so its load average is printed beside the figures (docs/design.md §12).

    python benchmarks/simtime.py [N ...] [--mission S] [--no-wall] [--processes P]   (sizes: 100 1000)

Measured 2026-11-26 on the 2-core machine shared with other jobs (docs/experiments.md, "Simulated
time, seeds and replay"), timers in 1 ms slots: 100 agents 11.3x real time at load 1.7-2.6 (11.8x
per CPU second), 5.5x at load 8; 1,000 agents 0.7x at load 1.7-5.4 (1.0x per CPU second). Over two
agent processes 1,800 rounds of the shared clock per simulated second (2,000 for 1,000 agents)
cost more than the agents compute: 100 agents 2.5x at load 3.5 against 11.8x in one process.

Measured 2026-11-27, same machine, the simulated clock's 50 ms timer grid (antalate_lcm/core/
executor.py, ``_SIM_GRID_MS``) alternated with the 1 ms slots before it, two runs each
(docs/experiments.md, "Simulated time over several processes"): 100 agents in one process 21.6x and
22.2x real time at load 2.5-3.0 (22-23x per CPU second; 13.5x and 14.4x before), 9.8x at load 8;
over two processes 17.6x and 14.1x (3.2x and 3.5x before) with 40 rounds per simulated second
instead of 1,802. 1,000 agents: one process 1.0x and 1.5x at load 1.8-2.7 (1.3x and 1.1x before:
the agents' own work dominates), two processes 1.1x and 1.4x (1.0x and 0.7x before) with 40 rounds
instead of 2,000 and a third less CPU. Goal met for 100 agents at low load; not for 1,000 (2x).

Measured 2026-11-27 later, load 2-6, main alternated with the run's stop in C (docs/experiments.md,
"Where a simulated second of 1,000 agents goes"): 100 agents 16.4-18.6x (main 8.4-13.7x), simulated
time 508-644 us of CPU per agent-second against the wall clock's 1,112-1,456; 1,000 agents 0.6-0.8x
(main 0.4-0.6x), 863-954 us per agent-second: 2x on one core needs 500, the agents' own work.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

CONFIG = """
[agent]
name = "b"
[buses]
lan = "memq://"
[topics]
default_bus = "lan"
[hlc]
autopilot = "sim"
default_takeoff_altitude = 5.0
[[bma]]
name = "swarm"
[[bma.behaviors]]
plugin = "dovrat_swarm"
activate_on = ["MISSION"]
[bma.behaviors.params]
forward_speed = 2.0
"""
SCRIPT = """
mission_time = {mission}
timeout = 600.0
[[direction]]
at = 5.0
azimuth = 90.0
"""


def child(config: str, agents: int, script: str, out: str, speed: str, processes: int) -> None:
    """One flight from this process (and its agent processes); its outcome as JSON on stdout."""
    import logging
    import math
    import resource

    from antalate_lcm.runtime.experiment import Experiment, run
    from antalate_lcm.runtime.script import load_script

    logging.basicConfig(level=logging.WARNING)
    outcome = run(
        Experiment(
            config_path=config,
            agents=agents,
            processes=processes,
            script=load_script(script),
            output=out,
            force=True,
            speed=math.inf if speed == "max" else None,
            seed=1,
            log_level="WARNING",
            measure=False,
        )
    )
    # The agent processes' CPU (waited for, so counted here) beside this one's.
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    result = {k: outcome.to_json()[k] for k in ("real_s", "simulated_s", "cpu_s")}
    result["cpu_s"] += children.ru_utime + children.ru_stime
    print(json.dumps({"code": outcome.code, "rounds": outcome.clock_rounds, **result}))


def fly(tmp: Path, agents: int, speed: str, processes: int = 1) -> dict[str, float]:
    # Agents in other processes are reached over a bus that crosses processes (on simulated time
    # it never touches the network: runtime/time_coordinator.py).
    config = tmp / ("swarm.toml" if processes == 1 else "swarm-udpm.toml")
    proc = subprocess.run(
        [sys.executable, __file__, "--child", str(config), str(agents), str(tmp / "script.toml")]
        + [str(tmp / f"{agents}-{speed}-{processes}.lcm"), speed, str(processes)],
        capture_output=True,
        text=True,
        check=False,
    )
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        sys.exit(f"the flight of {agents} agents ({speed}) failed:\n{proc.stdout}\n{proc.stderr[-3000:]}")
    result: dict[str, float] = json.loads(lines[-1])
    if result["code"] != 0:
        print(f"  (the flight of {agents} agents, {speed}, did not end with every agent in STANDBY)")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("sizes", nargs="*", type=int, default=[100, 1000])
    parser.add_argument("--mission", type=float, default=30.0, help="s of mission (default 30)")
    parser.add_argument("--no-wall", action="store_true", help="only the runs on simulated time")
    parser.add_argument(
        "--processes",
        type=int,
        default=2,
        metavar="P",
        help="also fly each size over P agent processes on one simulated clock (default 2; 1: not)",
    )
    parser.add_argument("--child", nargs=6, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        config, agents, script, out, speed, processes = args.child
        child(config, int(agents), script, out, speed, int(processes))
        return
    with tempfile.TemporaryDirectory(prefix="antalate-simtime-") as d:
        tmp = Path(d)
        (tmp / "swarm.toml").write_text(CONFIG)
        (tmp / "swarm-udpm.toml").write_text(CONFIG.replace('"memq://"', '"udpm://239.255.76.98:7698?ttl=0"'))
        (tmp / "script.toml").write_text(SCRIPT.format(mission=args.mission))
        print(
            f"{'agents':>6}  {'procs':>5}  {'simulated':>9}  {'real':>7}  {'speed-up':>8}  {'cpu':>7}  "
            f"{'sim/cpu':>7}  {'us/ag-s':>7}   wall clock: real, core, us/ag-s   load   rounds/sim s"
        )
        for n in args.sizes:
            load_before = os.getloadavg()[0]
            sims = [(1, fly(tmp, n, "max"))]
            if args.processes > 1:
                sims.append((args.processes, fly(tmp, n, "max", args.processes)))
            wall = None if args.no_wall else fly(tmp, n, "wall")
            load = f"{load_before:.1f}-{os.getloadavg()[0]:.1f}"
            for p, sim in sims:
                s, r, c = sim["simulated_s"], sim["real_s"], sim["cpu_s"]
                w = (
                    "-"
                    if wall is None or p > 1
                    else f"{wall['real_s']:7.1f} s, {100 * wall['cpu_s'] / wall['real_s']:4.0f} %, "
                    f"{1e6 * wall['cpu_s'] / (n * wall['real_s']):4.0f}"
                )
                rounds = "-" if sim.get("rounds") is None else f"{sim['rounds'] / s:.0f}"
                print(
                    f"{n:>6}  {p:>5}  {s:>7.1f} s  {r:>5.1f} s  {s / r:>7.1f}x  {c:>5.1f} s  {s / c:>6.1f}x"
                    f"  {1e6 * c / (n * s):>7.0f}   {w}   {load}   {rounds}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
