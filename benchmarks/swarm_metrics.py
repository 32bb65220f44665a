"""Fly the template swarm (``dovrat_swarm`` + the station's peer detection) with a direction command,
record it with ``lcm-logger`` and measure it with ``antalate analyze``: does it hold together, and
does it go where it is told?

Goal (the figures in the README): over the mission the swarm's radius (largest distance of an agent
to the centroid) stays within twice its starting radius, and the centroid drifts within 20 degrees
of the commanded azimuth.

    python benchmarks/swarm_metrics.py [--agents 10] [--mission-time 300] [--azimuth 45] [--speed 1]
                                       [--log swarm.lcm] [--plot docs/swarm-10-agents.png]

It runs in a private network namespace (never on the host network), in one process like
``antalate demo --headless``, with the demo's swarm and station parameters. Exit status 0 when both
goals are met. Expect mission time + about a minute (take-off and the flight home).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._netns import ensure_private_netns  # noqa: E402

MAX_RADIUS_RATIO = 2.0
MAX_DRIFT_ERROR_DEG = 20.0


def fly(agents: int, mission_time: float, azimuth: float, speed: float) -> tuple[bool, str]:
    """The demo's headless flight, with an operator timeout long enough for a long mission."""
    from antalate_lcm.core.node import Node, NodeSettings
    from antalate_lcm.runtime.agent import agent_nodes
    from antalate_lcm.runtime.demo import DEMO_URL, build_swarm, open_context, start_station
    from antalate_lcm.runtime.launch import run_until_signal
    from antalate_lcm.runtime.scripted_operator import Phase, ScriptedOperator

    station = start_station()
    try:
        context, url = open_context(DEMO_URL)
        configs = build_swarm(agents, url, station=station.url)
        nodes: list[Node] = [node for cfg in configs for node in agent_nodes(cfg, context)]
        operator = ScriptedOperator(
            NodeSettings.from_config(configs[0], agent="operator"),
            context,
            expected_agents=agents,
            mission_time=mission_time,
            direction=(azimuth, speed),
            timeout=mission_time + 300.0,
        )
        nodes.append(operator)
        run_until_signal(context, nodes, stop_event=threading.Event(), poll=lambda: operator.finished)
        return operator.phase is Phase.DONE, operator.report()
    finally:
        station.stop()


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--agents", type=int, default=10)
    parser.add_argument("--mission-time", type=float, default=300.0, help="s in MISSION (default 300)")
    parser.add_argument("--azimuth", type=float, default=45.0, help="commanded direction, deg (default 45)")
    parser.add_argument("--speed", type=float, default=1.0, help="commanded drift speed, m/s (default 1)")
    parser.add_argument("--log", help="where to keep the LCM log (default: a temporary file)")
    parser.add_argument("--plot", help="write the plot here (PNG)")
    args = parser.parse_args()
    ensure_private_netns()

    from antalate_lcm.apps.analysis import analyze_log, format_summary, plot_log
    from antalate_lcm.runtime.cli import native_lcm_tool
    from antalate_lcm.runtime.demo import DEMO_URL

    tmp = tempfile.TemporaryDirectory()
    log = Path(args.log) if args.log else Path(tmp.name) / "swarm.lcm"
    # The compiled logger itself (the lcm-logger on PATH is a wrapper that would not pass SIGTERM on).
    logger = subprocess.Popen(
        [native_lcm_tool("lcm-logger"), "--quiet", "--force", f"--lcm-url={DEMO_URL}", str(log)]
    )
    time.sleep(0.5)
    started = time.monotonic()
    try:
        ok, report = fly(args.agents, args.mission_time, args.azimuth, args.speed)
    finally:
        logger.terminate()
        logger.wait(10)
    print(report)
    print(f"flight: {time.monotonic() - started:.0f} s; log: {log} ({log.stat().st_size / 1e6:.1f} MB)\n")
    result = analyze_log(log)
    if args.plot:
        # This benchmark's own goal (the plot draws none unless asked): twice the starting radius.
        goals = (MAX_RADIUS_RATIO * result.start_radius,) if result.start_radius else ()
        _, result = plot_log(log, args.plot, goals=goals)
        print(f"plot: {args.plot}")
    print(format_summary(result))
    ratio = result.cohesion_ratio
    error = result.drift[0].error if result.drift else None
    radius_ok = ratio is not None and ratio <= MAX_RADIUS_RATIO
    drift_ok = error is not None and abs(error) <= MAX_DRIFT_ERROR_DEG
    print(
        f"\ngoal: radius within {MAX_RADIUS_RATIO:g}x the start: "
        f"{'met' if radius_ok else 'NOT met'} ({'n/a' if ratio is None else f'{ratio:.2f}x'}); "
        f"drift within {MAX_DRIFT_ERROR_DEG:g} deg: {'met' if drift_ok else 'NOT met'} "
        f"({'n/a' if error is None else f'{error:+.1f} deg'})"
    )
    tmp.cleanup()
    return 0 if ok and radius_ok and drift_ok else 1


if __name__ == "__main__":
    sys.exit(main())
