"""How many simulated agents a process holds: telemetry at 10 Hz, every state machine reacting
within 100 ms, and the memory it takes.

For each N it starts ``antalate agent --agents N --processes P`` (MC + HLC + sim per agent; P is one
process per 1,000 agents unless ``--processes`` says otherwise) in a private network namespace,
listens from this process with raw LCM, and prints:
- the time until every agent's MC is in STANDBY (target: within 30 s of the start),
- the telemetry rate received per agent, min / mean (target: every agent >= 9.5 Hz),
- the MC reaction time to a broadcast TAKEOFF (command sent → that agent's mc_state_t TAKEOFF
  received), p50 / p99 / max over the agents (target max < 100 ms),
- the HLC reaction (MC TAKEOFF → HLC TAKEOFF, the next link in the chain),
- the agent processes' RSS (summed; target < 1 GiB per 1,000 agents), CPU (% of one core, summed)
  and CPU per agent: microseconds of CPU per agent-second, which shows how the cost grows with N;
- then, every agent in MISSION hovering (homes 8 m apart), the same telemetry rate and CPU in flight
  (with ``--safety`` every HLC then filters its set-point each control tick).

    python benchmarks/agents.py [N ...] [--processes P] [--safety] [--repeat R] [--busy] [--tree DIR]
                                                            (default sizes: 500 1000 2000)

``--safety`` turns the separation filter on in every agent (``[safety] enabled``, docs/safety.md):
each process then feeds one swarm picture with every agent's telemetry, and each HLC filters its
velocity set-points in flight; benchmarks/safety_filter.py runs 1,000 agents both ways in one run.

Figures only (docs/design.md §12): the machine is shared, so the load average is printed beside them.

A reference workload is measured in the same run, just before each size starts, so figures from
two machines (or two moments of one) can be compared. ``ref`` (benchmarks/_reference.py, shared with
benchmarks/tui.py) is the CPU time one raw-lcm message
costs this machine now: one of a thousand senders' ``telemetry_t`` encoded by lcm-gen,
``lcm.publish``ed on the same udpm URL and decoded (µs, the mean of 20,000). ``@10 Hz`` is the µs
per agent-second scaled to the full telemetry rate (x 10 / the mean rate received): a process short
of core skips timer runs rather than bursting, so it does less work and spends less. ``x ref`` is
``@10 Hz`` divided by ``ref``: an agent's CPU a second in raw messages (it sends 20 a second:
telemetry at 10 Hz, its MC and HLC states at 5 Hz each). The ratio moves much less than the µs with
the machine's speed (docs/simulator.md, "Many agents in one process").

``--busy``: a second process spins on the other core for the whole run (a pure-Python loop), the
"something else running" of a laptop. ``--tree DIR``: run the agents from another checkout of
antalate (PYTHONPATH), e.g. ``git worktree add /tmp/base <commit>``, for a baseline measured in the
same session with the same listener and reference. ``--repeat R``: each size R times.

Measured 2026-11-26 on the 2-core machine, the commit before (3616f4f) and this one alternating,
>= 3 runs each: at load average 1.0-1.9 an agent costs 94-108 x ref (588-676 us/agent-s, ref
6.2-6.4 us), 121-126 x before; 1,000 agents in one process: STANDBY 0.9-1.0 s, telemetry min
9.8-10.0 Hz, MC max 27-44 ms, RSS 68 MiB, 59-68 % of a core. At load 3-7 (six other jobs): 79-96 x
ref here, 110-139 x before, and 1,000 agents got 36-42 % of a core and held 6.4-8.7 Hz. No kernel
drops in any run. The tables: docs/simulator.md.

Issue 32's second pass (sim flight step, slots, shared messages and parameters, enum members bound
once), 5b13bf3 against 8b4ebf1 in one session at load 6.8-14.4, 3 runs each: 103 -> 71 x ref on the
ground (681 -> 489 us per agent-second at 10 Hz), 108 -> 84 x ref hovering; with --busy 70 -> 63
and 89 -> 72 (docs/simulator.md, "Issue 32, second pass").
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._netns import ensure_private_netns  # noqa: E402
from benchmarks._reference import reference  # noqa: E402

URL = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608"


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (the launcher and its agent processes)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def proc_stats(pid: int) -> tuple[float, float]:
    """(RSS MiB, CPU seconds) of a process and its children, summed."""
    rss = cpu = 0.0
    ticks = os.sysconf("SC_CLK_TCK")
    for p in _tree(pid):
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    rss += int(line.split()[1]) / 1024
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        cpu += (int(fields[11]) + int(fields[12])) / ticks
    return rss, cpu


def rcvbuf_errors() -> int:
    """Datagrams this network namespace's kernel dropped for a full receive buffer (``Udp:
    RcvbufErrors`` of /proc/net/snmp). A socket's own drop count (below) also counts what its filter
    dropped: an agent process's socket drops the process's own datagrams on purpose
    (antalate_lcm/transports/udpm.py), so the agents' overflows are these less the listener's."""
    lines = [
        line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")
    ]
    return int(lines[1][lines[0].index("RcvbufErrors")])


def udp_drops(port: int) -> dict[int, int]:
    """Datagrams the kernel dropped per socket bound to ``port`` (socket inode -> drops), from
    /proc/net/udp of this network namespace: a full receive buffer, i.e. a reader that fell behind."""
    out: dict[int, int] = {}
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        f = line.split()
        if int(f[1].split(":")[1], 16) == port:
            out[int(f[9])] = int(f[12])
    return out


def busy_loop(stop_at: float) -> None:
    """The --busy process: pure Python arithmetic until ``stop_at`` (monotonic)."""
    x = 0
    while time.monotonic() < stop_at:
        for i in range(10_000):
            x = (x * 31 + i) % 1_000_003


def run(
    n: int, tmp: Path, processes: int | None, safety: bool = False, tree: Path | None = None
) -> dict[str, float]:
    import lcm

    from antalate_lcm.msgs import hlc_state_t, mc_state_t, operator_cmd_t
    from antalate_lcm.transports.udpm import UdpmReceiver

    cfg = tmp / "bench.toml"
    text = f'[agent]\nname = "b"\n[buses]\nlan = "{URL}"\n[hlc]\nautopilot = "sim"\n'
    if safety:
        # The filter's swarm picture hears every agent's TELEMETRY on the LAN: unsigned only by
        # choice (a private namespace here; a real swarm sets [security] swarm_key, docs/security.md).
        text += "[safety]\nenabled = true\n[security]\ninsecure = true\n"
    cfg.write_text(text)
    log = open(tmp / f"agents-{n}.log", "w")  # noqa: SIM115
    argv = [
        sys.executable,
        "-m",
        "antalate_lcm.cli",
        "--log-level",
        "WARNING",
        "agent",
        str(cfg),
        "--agents",
        str(n),
    ]
    if processes != 0:  # 0: leave the option out (a tree from before --processes, for a baseline)
        argv += ["--processes", str(processes or math.ceil(n / 1000))]
    env = None
    if tree is not None:  # the agents from another checkout; the listener stays this tree's
        env = dict(os.environ, PYTHONPATH=str(tree))
    started = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tree)
    lc = lcm.LCM(URL)  # to send the TAKEOFF
    # Listening on antalate's own udpm reader (antalate_lcm/transports/udpm.py): no liblcm receive thread
    # competing with the agents for the two cores; the kernel's drop count of this socket says
    # whether a rate below target was the agents' or this listener's.
    receiver = UdpmReceiver(URL)
    port = int(URL.rsplit(":", 1)[1].split("?")[0])
    mine = os.fstat(receiver.fileno()).st_ino
    lock = threading.Lock()
    telem: dict[str, int] = {}
    mc_takeoff: dict[str, float] = {}
    hlc_takeoff: dict[str, float] = {}
    standby: set[str] = set()
    mission: set[str] = set()

    def on_msg(channel: str, data: bytes) -> None:
        agent, _, topic = channel.partition("/")
        now = time.perf_counter()
        with lock:
            if topic == "TELEMETRY":
                telem[agent] = telem.get(agent, 0) + 1
            elif topic == "MC_STATE":
                st = mc_state_t.decode(data).state
                if st == mc_state_t.STANDBY:
                    standby.add(agent)
                elif st == mc_state_t.TAKEOFF and agent not in mc_takeoff:
                    mc_takeoff[agent] = now
                elif st == mc_state_t.MISSION:
                    mission.add(agent)
            elif (
                topic == "HLC_STATE"
                and hlc_state_t.decode(data).state == hlc_state_t.TAKEOFF
                and agent not in hlc_takeoff
            ):
                hlc_takeoff[agent] = now

    stop = threading.Event()

    def loop() -> None:
        import select

        while not stop.is_set():
            if select.select([receiver.fileno()], [], [], 0.05)[0]:
                receiver.drain(on_msg, 1_000)

    th = threading.Thread(target=loop, daemon=True)
    th.start()
    try:
        deadline = time.time() + 60
        while len(standby) < n and time.time() < deadline:
            time.sleep(0.1)
        if len(standby) < n:
            log.flush()
            tail = (tmp / f"agents-{n}.log").read_text().splitlines()[-5:]
            print("\n".join(f"    agent log: {line}" for line in tail), flush=True)
            return {"n": n, "error": float(len(standby))}
        standby_s = time.perf_counter() - started
        time.sleep(2.0)  # settle
        with lock:
            telem.clear()
        cpu0 = proc_stats(proc.pid)[1]
        drops0 = udp_drops(port)
        overflows0 = rcvbuf_errors()
        t0 = time.perf_counter()
        time.sleep(5.0)
        window = time.perf_counter() - t0
        rss, cpu1 = proc_stats(proc.pid)
        drops1 = udp_drops(port)
        overflows = rcvbuf_errors() - overflows0
        dropped = {ino: d - drops0.get(ino, 0) for ino, d in drops1.items()}
        with lock:
            rates = [
                telem.get(f"b-{i + 1:02d}" if n < 100 else f"b-{i + 1:03d}", 0) / window for i in range(n)
            ]
        cmd = operator_cmd_t()
        cmd.header.seq = 1
        cmd.header.agent = "bench"
        cmd.command = operator_cmd_t.TAKEOFF
        sent = time.perf_counter()
        lc.publish("SWARM/OPERATOR_CMD", cmd.encode())
        deadline2 = time.time() + 5
        while (len(mc_takeoff) < n or len(hlc_takeoff) < n) and time.time() < deadline2:
            time.sleep(0.05)
        with lock:
            mc_lat = [(t - sent) * 1000 for t in mc_takeoff.values()]
            hlc_lat = [(hlc_takeoff[a] - mc_takeoff[a]) * 1000 for a in hlc_takeoff if a in mc_takeoff]
        # In flight: every agent hovering in MISSION (with --safety each HLC filters its set-point on
        # every control tick against its neighbours, 8 m apart), the same 5 s window.
        deadline3 = time.time() + 60
        while len(mission) < n and time.time() < deadline3:
            time.sleep(0.2)
        flight: dict[str, float] = {"flying": float(len(mission))}
        if len(mission) == n:
            time.sleep(2.0)
            with lock:
                telem.clear()
            cpu2 = proc_stats(proc.pid)[1]
            t2 = time.perf_counter()
            time.sleep(5.0)
            window2 = time.perf_counter() - t2
            cpu3 = proc_stats(proc.pid)[1]
            with lock:
                flown = [telem.get(a, 0) / window2 for a in mission]
            flight.update(
                flight_hz_min=min(flown),
                flight_hz_mean=statistics.fmean(flown),
                flight_cpu_pct=100 * (cpu3 - cpu2) / window2,
                flight_us_per_agent_s=(cpu3 - cpu2) / window2 / n * 1e6,
            )
        return {
            "n": n,
            "standby_s": standby_s,
            "telemetry_hz_min": min(rates),
            "telemetry_hz_mean": statistics.fmean(rates),
            "mc_reacted": len(mc_takeoff),
            "mc_p50_ms": pct(mc_lat, 0.5),
            "mc_p99_ms": pct(mc_lat, 0.99),
            "mc_max_ms": max(mc_lat, default=float("nan")),
            "hlc_p50_ms": pct(hlc_lat, 0.5),
            "hlc_max_ms": max(hlc_lat, default=float("nan")),
            "rss_mib": rss,
            "cpu_pct": 100 * (cpu1 - cpu0) / window,
            "us_per_agent_s": (cpu1 - cpu0) / window / n * 1e6,
            "listener_dropped": dropped.get(mine, 0),
            "agents_dropped": max(0, overflows - dropped.get(mine, 0)),
            **flight,
        }
    finally:
        stop.set()
        th.join()
        receiver.close()
        pids = _tree(proc.pid)
        proc.terminate()  # the launcher passes it on to its agent processes
        try:
            proc.wait(90)  # a thousand agents take a while to land their nodes on a loaded machine
        except subprocess.TimeoutExpired:
            proc.kill()
        for pid in pids[1:]:  # nothing left behind to load the next size
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("sizes", nargs="*", type=int, default=[500, 1000, 2000])
    parser.add_argument(
        "--processes",
        type=int,
        help="agent processes (default: one per 1,000 agents; 0: no --processes option)",
    )
    parser.add_argument(
        "--safety", action="store_true", help="every agent with the separation filter on ([safety] enabled)"
    )
    parser.add_argument("--repeat", type=int, default=1, help="runs of each size")
    parser.add_argument("--busy", action="store_true", help="a second process spins for the whole run")
    parser.add_argument("--tree", type=Path, help="run the agents from this checkout (a baseline)")
    args = parser.parse_args()
    ensure_private_netns()
    tree = args.tree.resolve() if args.tree else None
    which = tree or Path(__file__).resolve().parent.parent
    commit = subprocess.run(
        ["git", "-C", str(which), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    print(
        f"CPUs: {os.cpu_count()}; load average {os.getloadavg()[0]:.2f} at start; agents from {which} "
        f"({commit or '?'}){'; a second process busy' if args.busy else ''}"
    )
    print(f"separation filter ([safety] enabled): {'on' if args.safety else 'off'}")
    busy = None
    if args.busy:
        import multiprocessing

        busy = multiprocessing.Process(target=busy_loop, args=(time.monotonic() + 3600,), daemon=True)
        busy.start()
    print(
        f"{'agents':>6} {'procs':>5} {'STANDBY s':>9} {'telem Hz min/mean':>18} {'MC react p50/p99/max ms':>24} "
        f"{'HLC react p50/max ms':>21} {'RSS MiB':>8} {'CPU %':>6} {'us/agent-s':>10} {'@10 Hz':>8} {'ref us':>6} "
        f"{'x ref':>6}"
        "  verdict"
    )
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for n in [size for size in args.sizes for _ in range(args.repeat)]:
                _measure(n, Path(tmp), args.processes, args.safety, tree)
    finally:
        if busy is not None:
            busy.terminate()


def _measure(n: int, tmp: Path, processes: int | None, safety: bool, tree: Path | None) -> None:
    procs = processes if processes is not None else math.ceil(n / 1000)
    ref = reference(URL)
    r = run(n, tmp, processes, safety, tree)
    if "error" in r:
        print(f"{n:>6} {procs:>5}  only {int(r['error'])} agents reached STANDBY within 60 s", flush=True)
        return
    # A process short of core skips timer runs (never bursts): it does less work, so it spends
    # less. Scaled to the full 10 Hz the CPU is what the agents' whole work costs.
    full = r["us_per_agent_s"] * 10.0 / max(r["telemetry_hz_mean"], 0.1)
    ok = (
        r["standby_s"] <= 30
        and r["telemetry_hz_min"] >= 9.5
        and r["mc_max_ms"] < 100
        and r["mc_reacted"] == n
        and r["rss_mib"] < 1024 * max(1.0, n / 1000)
    )
    print(
        f"{n:>6} {procs:>5} {r['standby_s']:>9.1f} {r['telemetry_hz_min']:>8.1f}/{r['telemetry_hz_mean']:<9.1f} "
        f"{r['mc_p50_ms']:>8.1f}/{r['mc_p99_ms']:.1f}/{r['mc_max_ms']:<8.1f} "
        f"{r['hlc_p50_ms']:>10.1f}/{r['hlc_max_ms']:<10.1f} {r['rss_mib']:>8.0f} {r['cpu_pct']:>6.0f} "
        f"{r['us_per_agent_s']:>10.0f} {full:>8.0f} {ref:>6.2f} {full / ref:>6.0f}  "
        f"{'OK' if ok else 'over target'}  (load {os.getloadavg()[0]:.2f})",
        flush=True,
    )
    print(
        f"{'':>12} kernel drops in the telemetry window: this listener's socket {r['listener_dropped']:.0f}, "
        f"the agent processes' sockets {r['agents_dropped']:.0f}",
        flush=True,
    )
    if "flight_cpu_pct" in r:
        # Scaled to the full rate as on the ground: a loaded process skips control and telemetry runs.
        flown_full = r["flight_us_per_agent_s"] * 10.0 / max(r["flight_hz_mean"], 0.1)
        print(
            f"{'':>12} in flight (all {n} in MISSION, hovering): telemetry min {r['flight_hz_min']:.1f} Hz, "
            f"CPU {r['flight_cpu_pct']:.0f} %, {r['flight_us_per_agent_s']:.0f} us/agent-s, "
            f"@10 Hz {flown_full:.0f}, x ref {flown_full / ref:.0f}",
            flush=True,
        )
    else:
        print(f"{'':>12} in flight: only {r['flying']:.0f} of {n} reached MISSION within 60 s", flush=True)


if __name__ == "__main__":
    main()
