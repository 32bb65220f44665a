"""What the safety filter costs (docs/safety.md): per agent-tick at 20, 200 and 1,000 agents, beside the
whole agent's cost from benchmarks/agents.py measured in the same run.

For each N the agents stand on a square grid (``--spacing`` m, 6 by default: every agent has peers
within its filter's horizon, the dense case) at 10 m, all heard by one `SwarmPicture` as in one
process; then every agent's `SafetyLayer.filter_velocity` runs with a wish towards the swarm's
centroid at 5 m/s (the interior agents' constraints are active). Printed:

- the filter's cost per agent-tick (µs per call, the mean over ``--ticks`` rounds of every agent),
  and its share of one core at 20 Hz for all N agents;
- the picture's cost per telemetry message fed (µs), and its share of one core at 10 Hz telemetry;
- the same filter with ``--spacing 30`` apart (nobody near: the fast path);
- then ``benchmarks/agents.py 1000`` twice, without and with the filter (``--safety``: 1,000 simulated
  agents in one process, every HLC fed the swarm picture): the 1,000-agents-per-process figures
  (STANDBY time, telemetry rate, reaction times, RSS, CPU per agent-second) both ways, in the same run.

    python benchmarks/safety_filter.py [--sizes 20 200 1000] [--ticks 20] [--no-agents]

Figures only: the machine is shared, so the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from antalate_lcm.agent.hlc.safety import SafetyLayer, new_picture  # noqa: E402
from antalate_lcm.base.geo import offset  # noqa: E402
from antalate_lcm.core.config import parse_config  # noqa: E402
from antalate_lcm.msgs import telemetry_t  # noqa: E402
from antalate_lcm.vehicles.base import Frame, VehicleState  # noqa: E402

LAT0, LON0 = 32.7767, 35.0231
CONTROL_HZ, TELEMETRY_HZ = 20.0, 10.0


def measure(n: int, spacing: float, ticks: int) -> dict[str, float]:
    config = parse_config(
        {"agent": {"name": "bench"}, "safety": {"enabled": True, "origin": [LAT0, LON0]}}, "bench"
    )
    picture = new_picture(config)
    side = math.ceil(math.sqrt(n))
    names = [f"a{i:04d}" for i in range(n)]
    where = [((i // side) * spacing, (i % side) * spacing) for i in range(n)]
    centre = (sum(w[0] for w in where) / n, sum(w[1] for w in where) / n)
    msgs = []
    for i in range(n):
        msg = telemetry_t()
        msg.lat, msg.lon = offset(LAT0, LON0, *where[i])
        msg.alt, msg.in_air = 10.0, True
        msgs.append(msg)
    # Feeding: every agent's telemetry, `ticks` times (fresh utimes each round).
    t0 = time.perf_counter()
    for r in range(ticks):
        for name, msg in zip(names, msgs, strict=True):
            msg.header.utime = r + 1
            picture.feed(name, msg, 0.0)
    feed_us = (time.perf_counter() - t0) / (ticks * n) * 1e6
    for name in names:
        picture.state(name, 3, 0.0)  # MISSION: every agent runs the filter (each takes half a pair's duty)
    picture.sweep(0.0)
    layers, states, wishes = [], [], []
    for i, name in enumerate(names):
        layers.append(SafetyLayer(name, config.with_agent_name(name), picture))
        states.append(VehicleState(connected=True, link_age=0.0, lat=msgs[i].lat, lon=msgs[i].lon, alt=10.0))
        dn, de = centre[0] - where[i][0], centre[1] - where[i][1]
        d = math.hypot(dn, de) or 1.0
        wishes.append((dn / d * 5.0, de / d * 5.0))
    modified = 0
    t0 = time.perf_counter()
    for _ in range(ticks):
        for layer, state, wish in zip(layers, states, wishes, strict=True):
            out = layer.filter_velocity(state, wish[0], wish[1], 0.0, Frame.NED, 0.05)
            modified += bool(out is not None and out.decision.modified)
    filter_us = (time.perf_counter() - t0) / (ticks * n) * 1e6
    return {
        "filter_us": filter_us,
        "feed_us": feed_us,
        "modified": modified / (ticks * n),
        "core_share": (filter_us * CONTROL_HZ + feed_us * TELEMETRY_HZ) * n / 1e6,
        "us_per_agent_s": filter_us * CONTROL_HZ + feed_us * TELEMETRY_HZ,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", nargs="*", type=int, default=[20, 200, 1000])
    parser.add_argument("--spacing", type=float, default=6.0)
    parser.add_argument("--ticks", type=int, default=20)
    parser.add_argument("--no-agents", action="store_true", help="skip benchmarks/agents.py 1000")
    args = parser.parse_args()
    print(f"CPUs: {os.cpu_count()}; load average {os.getloadavg()[0]:.2f} at start")
    print(
        f"{'agents':>6} {'spacing m':>9} {'filter us/call':>14} {'modified':>8} {'feed us/msg':>11}"
        f" {'us/agent-s':>10} {'core share':>10}"
    )
    for spacing in (args.spacing, 30.0):
        for n in args.sizes:
            r = measure(n, spacing, args.ticks)
            print(
                f"{n:>6} {spacing:>9.0f} {r['filter_us']:>14.1f} {r['modified']:>8.0%} {r['feed_us']:>11.1f}"
                f" {r['us_per_agent_s']:>10.0f} {r['core_share']:>10.0%}   (load {os.getloadavg()[0]:.2f})",
                flush=True,
            )
    if args.no_agents:
        return
    agents = Path(__file__).resolve().parent / "agents.py"
    for extra in ([], ["--safety"]):
        print(f"\nbenchmarks/agents.py 1000 {' '.join(extra)}, the same run:", flush=True)
        subprocess.run([sys.executable, str(agents), "1000", *extra], check=False)


if __name__ == "__main__":
    main()
