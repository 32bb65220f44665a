"""Per-thread scheduler figures of benchmarks/bus.py's processes over one of its runs: CPU time,
run-queue wait (from a wake-up until the thread runs) and voluntary / involuntary switches, read
from /proc/<pid>/task/<tid>/schedstat and status (docs/simulator.md, "The node round trip under
load"). Start it beside the benchmark; it only reads /proc, on the host side of the namespace.

    .venv/bin/python benchmarks/bus.py --only latency & .venv/bin/python benchmarks/schedstat.py 50

Per ping: divide by the pings each echo answered (about 6,000 a run: 5,000 timed and the warm-ups).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

#: utime+stime ns, run-queue wait ns, time slices, voluntary and involuntary switches
Sample = tuple[int, int, int, int, int]


def bus_processes() -> dict[int, str]:
    """benchmarks/bus.py's processes now: the pinger (``--inside``) and each echo or sink (``--peer``)."""
    out: dict[int, str] = {}
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = [a.decode(errors="replace") for a in (proc / "cmdline").read_bytes().split(b"\0") if a]
        except OSError:
            continue
        if not any(a.endswith("benchmarks/bus.py") for a in argv):
            continue
        if "--peer" in argv:
            i = argv.index("--peer")
            out[int(proc.name)] = "-".join(argv[i + 1 : i + 3])
        elif "--inside" in argv:
            out[int(proc.name)] = "pinger"
    return out


def threads(pid: int) -> dict[int, Sample]:
    out: dict[int, Sample] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            run, wait, slices = (int(x) for x in (task / "schedstat").read_text().split())
            status = (task / "status").read_text()
        except OSError:
            continue  # the thread ended
        vol = int(status.split("\nvoluntary_ctxt_switches:")[1].split()[0])
        invol = int(status.split("nonvoluntary_ctxt_switches:")[1].split()[0])
        out[int(task.name)] = (run, wait, slices, vol, invol)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("seconds", type=float, help="how long to sample (the benchmark's run)")
    args = parser.parse_args()
    first: dict[tuple[int, str], dict[int, Sample]] = {}
    last: dict[tuple[int, str], dict[int, Sample]] = {}
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        for pid, name in bus_processes().items():
            try:
                now = threads(pid)
            except OSError:
                continue  # the process ended
            first.setdefault((pid, name), now)
            # Per thread, its last sample alive: a bus's threads end before its process does.
            last.setdefault((pid, name), {}).update(now)
        time.sleep(0.2)
    print(f"{'process':18s} {'thread':>7} {'CPU s':>6} {'rq-wait s':>9} {'voluntary':>9} {'involuntary':>11}")
    for (pid, name), per_thread in sorted(last.items(), key=lambda kv: kv[0][1]):
        for tid, (run, wait, _slices, vol, invol) in per_thread.items():
            r0, w0, _s0, v0, i0 = first[(pid, name)].get(tid, (0, 0, 0, 0, 0))
            if vol - v0 < 100:
                continue  # a thread that sleeps through the run (the main thread reading stdin)
            print(
                f"{name:18s} {tid:>7} {(run - r0) / 1e9:6.2f} {(wait - w0) / 1e9:9.3f} {vol - v0:9d} {invol - i0:11d}"
            )


if __name__ == "__main__":
    main()
