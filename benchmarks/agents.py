"""How many simulated agents one process holds: telemetry at 10 Hz, every state machine reacting
within 100 ms, and the memory it takes.

For each N it starts ``antalate agent --agents N`` (MC + HLC + sim per agent, one process) in a
private network namespace, listens from a second process with raw LCM, and prints:
- the telemetry rate received per agent (target 10 Hz),
- the MC reaction time to a broadcast TAKEOFF (command sent → that agent's mc_state_t TAKEOFF
  received), p50 / p99 / max over the agents (target max ≤ 100 ms),
- the HLC reaction (MC TAKEOFF → HLC TAKEOFF, the next link in the chain),
- the agent process's RSS and CPU.

    python benchmarks/agents.py [N ...]        (default: 50 100 200 300)
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._netns import ensure_private_netns  # noqa: E402

URL = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608"


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def proc_stats(pid: int) -> tuple[float, float]:
    """(RSS MiB, CPU seconds) of a process."""
    rss = 0.0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return rss, (int(fields[11]) + int(fields[12])) / ticks


def run(n: int, tmp: Path) -> dict[str, float]:
    import lcm

    from antalate_lcm.msgs import hlc_state_t, mc_state_t, operator_cmd_t

    cfg = tmp / "bench.toml"
    cfg.write_text(f'[agent]\nname = "b"\n[buses]\nlan = "{URL}"\n[hlc]\nautopilot = "sim"\n')
    log = open(tmp / f"agents-{n}.log", "w")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "antalate_lcm.cli", "--log-level", "WARNING", "agent", str(cfg), "--agents", str(n)],
        stdout=log, stderr=subprocess.STDOUT,
    )
    lc = lcm.LCM(URL)
    lock = threading.Lock()
    telem: dict[str, int] = {}
    mc_takeoff: dict[str, float] = {}
    hlc_takeoff: dict[str, float] = {}
    standby: set[str] = set()

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
            elif (
                topic == "HLC_STATE"
                and hlc_state_t.decode(data).state == hlc_state_t.TAKEOFF
                and agent not in hlc_takeoff
            ):
                hlc_takeoff[agent] = now

    lc.subscribe(".*", on_msg).set_queue_capacity(1_000_000)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            lc.handle_timeout(50)

    th = threading.Thread(target=loop, daemon=True)
    th.start()
    try:
        deadline = time.time() + 60
        while len(standby) < n and time.time() < deadline:
            time.sleep(0.2)
        if len(standby) < n:
            return {"n": n, "error": float(len(standby))}
        time.sleep(2.0)  # settle
        with lock:
            telem.clear()
        cpu0 = proc_stats(proc.pid)[1]
        t0 = time.perf_counter()
        time.sleep(5.0)
        window = time.perf_counter() - t0
        rss, cpu1 = proc_stats(proc.pid)
        with lock:
            rates = [telem.get(f"b-{i + 1:02d}" if n < 100 else f"b-{i + 1:03d}", 0) / window for i in range(n)]
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
        return {
            "n": n,
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
        }
    finally:
        stop.set()
        th.join()
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


def main() -> None:
    ensure_private_netns()
    sizes = [int(a) for a in sys.argv[1:]] or [50, 100, 200, 300]
    print(f"{'agents':>6} {'telem Hz min/mean':>18} {'MC react p50/p99/max ms':>24} {'HLC react p50/max ms':>21} "
          f"{'RSS MiB':>8} {'CPU %':>6}  verdict")
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            r = run(n, Path(tmp))
            if "error" in r:
                print(f"{n:>6}  only {int(r['error'])} agents reached STANDBY within 60 s")
                continue
            ok = r["telemetry_hz_min"] >= 9.0 and r["mc_max_ms"] <= 100 and r["hlc_max_ms"] <= 100 and r["mc_reacted"] == n
            print(
                f"{n:>6} {r['telemetry_hz_min']:>8.1f}/{r['telemetry_hz_mean']:<9.1f} "
                f"{r['mc_p50_ms']:>8.1f}/{r['mc_p99_ms']:.1f}/{r['mc_max_ms']:<8.1f} "
                f"{r['hlc_p50_ms']:>10.1f}/{r['hlc_max_ms']:<10.1f} {r['rss_mib']:>8.0f} {r['cpu_pct']:>6.0f}  "
                f"{'OK' if ok else 'over target'}",
                flush=True,
            )


if __name__ == "__main__":
    main()
