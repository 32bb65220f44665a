"""Station throughput and latency with 100, 1,000 and 5,000 agents in the database.

    .venv/bin/python benchmarks/station.py [--seconds 5] [--client both|httpx|raw] [--agents 100,1000,5000]

What it does, and why:

* The station runs in its own process (`StationServer` in a ``multiprocessing`` child) on
  127.0.0.1 with a real SQLite file in a temporary directory, as ``antalate station`` serves it,
  so client and server do not share a GIL. History recording is on (the default).
* Agents register through the API (first contact → token) at random positions in a 3 km × 3 km
  field, then report with small random moves. ``stale_after_s`` is raised to 120 s so every
  registered agent is a live peer: at 5,000 agents the index really holds 5,000 positions.
* Two load generators, each closed-loop (one request in flight per connection, like an OSC):
  - ``httpx``: ``--clients`` processes, each a keep-alive ``httpx.Client``. Realistic, but httpx
    spends ~0.6 ms of CPU per request, so on a 2-core machine the clients eat more CPU than the
    station and the figure says as much about httpx as about the server.
  - ``raw``: one process, ``--connections`` keep-alive sockets speaking minimal HTTP/1.1 with
    asyncio (~0.05 ms per request): this measures the station.
  The station's own CPU time per report (from /proc) is printed for both; it is the number that
  does not depend on the client or on other load on the machine.
* Separately, in this process, the index + sector query alone is timed against a brute-force
  scan of every agent, in the fixed field (density grows with the swarm) and at constant density
  (field grows with the swarm), to show what the spatial index buys.

Loopback only; bounded in time (about a minute with the defaults). Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import math
import multiprocessing as mp
import os
import random
import sqlite3
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from antalate_lcm.station import RateLimits, StationServer, StationSettings  # noqa: E402
from antalate_lcm.station._spatial import GridIndex  # noqa: E402
from antalate_lcm.station.sector import detect, search_box  # noqa: E402

ORIGIN = (32.7767, 35.0231)  # a field near Haifa
FIELD_M = 3000.0
RANGE_M = 100.0
FOV_DEG = 60.0
M_PER_DEG_LAT = 110_900.0

Agent = tuple[str, str, float, float]  # token, name, lat, lon


def _position(rng: random.Random, field_m: float = FIELD_M) -> tuple[float, float]:
    north, east = rng.uniform(0, field_m), rng.uniform(0, field_m)
    lat = ORIGIN[0] + north / M_PER_DEG_LAT
    lon = ORIGIN[1] + east / (M_PER_DEG_LAT * math.cos(math.radians(ORIGIN[0])))
    return lat, lon


def _report(token: str | None, name: str, lat: float, lon: float, heading: float) -> bytes:
    """The JSON an OSC sends: full telemetry, both states, no feedback."""
    return json.dumps(
        {
            "token": token,
            "mc_state": "MISSION",
            "hlc_state": "AIRBORNE",
            "telemetry": {
                "agent": name,
                "lat": lat,
                "lon": lon,
                "alt": 20.0,
                "heading": heading,
                "vn": 1.0,
                "ve": 0.5,
                "vd": 0.0,
                "battery": 87.5,
                "armed": True,
                "in_air": True,
                "mode": "SIM",
            },
            "feedback": None,
        }
    ).encode()


class _Walk:
    """Agents' reports in turn, each a small random move and turn from the last."""

    def __init__(self, agents: list[Agent], seed: int) -> None:
        self._rng = random.Random(seed)
        self._state = [[tok, name, lat, lon, self._rng.uniform(0, 360)] for tok, name, lat, lon in agents]
        self._i = 0

    def next_body(self) -> bytes:
        a = self._state[self._i % len(self._state)]
        self._i += 1
        a[2] += self._rng.uniform(-2e-5, 2e-5)
        a[3] += self._rng.uniform(-2e-5, 2e-5)
        a[4] = (a[4] + self._rng.uniform(-10, 10)) % 360.0
        return _report(a[0], a[1], a[2], a[3], a[4])


def _serve(db_path: str, conn: Connection) -> None:
    # Every simulated agent registers and reports from 127.0.0.1: the per-address and per-agent
    # limits (which a real deployment keeps) would measure the limiter, not the station.
    no_limits = RateLimits(
        registrations_per_minute=None, reports_per_second=None, address_reports_per_second=None
    )
    settings = StationSettings(
        db_path=db_path, range_m=RANGE_M, fov_deg=FOV_DEG, stale_after_s=120.0, rate_limits=no_limits
    )
    with StationServer(settings) as server:
        conn.send(server.url)
        conn.recv()  # any message = stop


# -- load generators (each runs in its own process) --------------------------------------------------


def _httpx_client(
    url: str, agents: list[Agent], seconds: float, seed: int, start: Any, out: Connection
) -> None:
    walk = _Walk(agents, seed)
    latencies: list[float] = []
    errors = 0
    headers = {"content-type": "application/json"}
    with httpx.Client(base_url=url, timeout=10.0) as client:
        for _ in range(20):  # warm the connection and the server's code paths
            client.post("/api/report", content=walk.next_body(), headers=headers)
        start.wait()  # every client measures over the same window
        cpu0 = time.process_time()
        end = time.perf_counter() + seconds
        while True:
            body = walk.next_body()
            t0 = time.perf_counter()
            if t0 >= end:
                break
            r = client.post("/api/report", content=body, headers=headers)
            latencies.append(time.perf_counter() - t0)
            errors += r.status_code != 200
    out.send((latencies, errors, time.process_time() - cpu0))


async def _raw_connection(
    host: str,
    port: int,
    walk: _Walk,
    end_at: list[float],
    latencies: list[float],
    errors: list[int],
    ready: asyncio.Event,
) -> None:
    reader, writer = await asyncio.open_connection(host, port)
    head = b"POST /api/report HTTP/1.1\r\nHost: %s\r\nContent-Type: application/json\r\nContent-Length: %d\r\n\r\n"
    warm = 20
    try:
        while True:
            if warm == 0:
                await ready.wait()
            body = walk.next_body()
            t0 = time.perf_counter()
            if warm == 0 and t0 >= end_at[0]:
                break
            writer.write(head % (host.encode(), len(body)) + body)
            status_line = await reader.readuntil(b"\r\n")
            headers = await reader.readuntil(b"\r\n\r\n")
            length = 0
            for line in headers.split(b"\r\n"):
                if line[:15].lower() == b"content-length:":
                    length = int(line[15:])
            await reader.readexactly(length)
            if warm:
                warm -= 1
                continue
            latencies.append(time.perf_counter() - t0)
            if status_line.split(b" ", 2)[1] != b"200":
                errors[0] += 1
    finally:
        writer.close()


def _raw_client(
    url: str, agents: list[Agent], seconds: float, connections: int, start: Any, out: Connection
) -> None:
    host, port = url.removeprefix("http://").rsplit(":", 1)
    latencies: list[float] = []
    errors = [0]

    async def run() -> float:
        ready = asyncio.Event()
        end_at = [math.inf]
        tasks = [
            asyncio.create_task(
                _raw_connection(
                    host, int(port), _Walk(agents[k::connections], 2000 + k), end_at, latencies, errors, ready
                )
            )
            for k in range(connections)
        ]
        await asyncio.sleep(0.5)  # warm-up requests
        await asyncio.get_running_loop().run_in_executor(None, start.wait)
        cpu0 = time.process_time()
        end_at[0] = time.perf_counter() + seconds
        ready.set()
        await asyncio.gather(*tasks)
        return time.process_time() - cpu0

    cpu = asyncio.run(run())
    out.send((latencies, errors[0], cpu))


# -- phases ------------------------------------------------------------------------------------------


def _register(url: str, names: list[str], rng: random.Random) -> list[Agent]:
    agents = []
    with httpx.Client(base_url=url, timeout=10.0) as client:
        for name in names:
            lat, lon = _position(rng)
            r = client.post(
                "/api/report",
                content=_report(None, name, lat, lon, rng.uniform(0, 360)),
                headers={"content-type": "application/json"},
            )
            r.raise_for_status()
            agents.append((r.json()["token"], name, lat, lon))
    return agents


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (all its threads), from /proc; NaN off Linux."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass
class Phase:
    rate: float
    p50_ms: float
    p99_ms: float
    errors: int
    server_cpu_us: float
    client_cpu_us: float


def _load_phase(kind: str, url: str, server_pid: int, agents: list[Agent], args: argparse.Namespace) -> Phase:
    ctx = mp.get_context("spawn")
    if kind == "httpx":
        start = ctx.Barrier(args.clients + 1)
        jobs = [
            (_httpx_client, (url, agents[k :: args.clients], args.seconds, 1000 + k, start))
            for k in range(args.clients)
        ]
    else:
        start = ctx.Barrier(2)
        jobs = [(_raw_client, (url, agents, args.seconds, args.connections, start))]
    pipes, procs = [], []
    for target, job_args in jobs:
        parent, child = ctx.Pipe(duplex=False)
        p = ctx.Process(target=target, args=(*job_args, child), daemon=True)
        p.start()
        pipes.append(parent)
        procs.append(p)
    start.wait(timeout=60)
    server_cpu0 = _cpu_seconds(server_pid)
    latencies: list[float] = []
    errors = 0
    client_cpu = 0.0
    for parent in pipes:
        lat, err, cpu = parent.recv()
        latencies.extend(lat)
        errors += err
        client_cpu += cpu
    server_cpu = _cpu_seconds(server_pid) - server_cpu0
    for p in procs:
        p.join(10)
    latencies.sort()
    n = len(latencies)
    return Phase(
        rate=n / args.seconds,
        p50_ms=latencies[n // 2] * 1e3,
        p99_ms=latencies[min(n - 1, int(n * 0.99))] * 1e3,
        errors=errors,
        server_cpu_us=server_cpu / n * 1e6,
        client_cpu_us=client_cpu / n * 1e6,
    )


def _sensing_cost(
    n: int, field_m: float, rng: random.Random, queries: int = 2000
) -> tuple[float, float, float]:
    """µs per report for the index + sector test, for a brute-force scan, and the mean candidates."""
    positions = [_position(rng, field_m) for _ in range(n)]
    index = GridIndex(RANGE_M / 2.0)
    for i, (lat, lon) in enumerate(positions):
        index.update(i, lat, lon, 0.0)
    picks = [(rng.randrange(n), rng.uniform(0, 360)) for _ in range(queries)]
    t0 = time.perf_counter()
    for i, heading in picks:
        lat, lon = positions[i]
        box = search_box(lat, lon, heading, RANGE_M, FOV_DEG)
        detect(lat, lon, heading, index.candidates(*box, exclude=i), RANGE_M, FOV_DEG)
    t_index = (time.perf_counter() - t0) / queries * 1e6
    few = picks[:200]
    candidates = sum(
        sum(1 for _ in index.candidates(*search_box(*positions[i], h, RANGE_M, FOV_DEG), exclude=i))
        for i, h in few
    )
    t0 = time.perf_counter()
    for i, heading in few:
        lat, lon = positions[i]
        detect(lat, lon, heading, (p for j, p in enumerate(positions) if j != i), RANGE_M, FOV_DEG)
    t_brute = (time.perf_counter() - t0) / len(few) * 1e6
    return t_index, t_brute, candidates / len(few)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", default="100,1000,5000", help="comma-separated swarm sizes (cumulative)")
    parser.add_argument(
        "--seconds", type=float, default=5.0, help="measurement time per swarm size and client"
    )
    parser.add_argument("--client", choices=("both", "httpx", "raw"), default="both")
    parser.add_argument("--clients", type=int, default=3, help="httpx client processes")
    parser.add_argument("--connections", type=int, default=8, help="raw client connections")
    args = parser.parse_args()
    sizes = sorted(int(s) for s in args.agents.split(","))
    kinds = ("httpx", "raw") if args.client == "both" else (args.client,)
    rng = random.Random(42)

    stack = " + ".join(
        name if importlib.util.find_spec(name) else f"no {name}" for name in ("uvloop", "httptools")
    )
    print(
        f"station benchmark: field {FIELD_M / 1000:.0f} km × {FIELD_M / 1000:.0f} km, range {RANGE_M:.0f} m, "
        f"fov {FOV_DEG:.0f}°, {args.seconds:g} s per size and client, {os.cpu_count()} CPUs, "
        f"load average {os.getloadavg()[0]:.2f}, uvicorn with {stack}"
    )
    print("\nsensing alone, in this process (µs per report; brute = exact test of every agent):")
    print(f"{'agents':>7} {'field':>8} {'index':>8} {'brute':>9} {'candidates':>11}")
    for label, field_of in (
        ("fixed", lambda n: FIELD_M),
        ("density", lambda n: FIELD_M * math.sqrt(n / sizes[-1])),
    ):
        for n in sizes:
            field_m = field_of(n)
            t_index, t_brute, cands = _sensing_cost(n, field_m, rng)
            print(
                f"{n:>7} {field_m / 1000:>6.1f}km {t_index:>8.1f} {t_brute:>9.1f} {cands:>11.1f}   ({label})"
            )

    with tempfile.TemporaryDirectory() as tmp:
        db_path = os.path.join(tmp, "station.sqlite")
        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe()
        server = ctx.Process(target=_serve, args=(db_path, child), daemon=True)
        server.start()
        url = parent.recv()
        print(
            f"\nHTTP, station at {url}, database {db_path} "
            f"(httpx: {args.clients} processes; raw: {args.connections} connections):"
        )
        print(
            f"{'agents':>7} {'client':>7} {'reports/s':>10} {'p50 ms':>8} {'p99 ms':>8} {'errors':>7}"
            f" {'server CPU µs/report':>21} {'client CPU µs/report':>21}"
        )
        agents: list[Agent] = []
        try:
            for n in sizes:
                before = len(agents)
                t0 = time.perf_counter()
                agents += _register(url, [f"uav{i:05d}" for i in range(len(agents), n)], rng)
                reg_s = time.perf_counter() - t0
                for kind in kinds:
                    ph = _load_phase(kind, url, server.pid or 0, agents, args)
                    print(
                        f"{n:>7} {kind:>7} {ph.rate:>10.0f} {ph.p50_ms:>8.2f} {ph.p99_ms:>8.2f} {ph.errors:>7}"
                        f" {ph.server_cpu_us:>21.0f} {ph.client_cpu_us:>21.0f}"
                    )
                print(f"{'':>7} (first contact of {n - before} new agents took {reg_s:.1f} s, one at a time)")
        finally:
            parent.send("stop")
            server.join(20)
        with sqlite3.connect(db_path) as conn:
            rows = conn.execute("SELECT COUNT(*) FROM reports").fetchone()[0]
            n_agents = conn.execute("SELECT COUNT(*) FROM agents").fetchone()[0]
        print(
            f"\ndatabase after the run: {n_agents} agents, {rows} history rows "
            f"({os.path.getsize(db_path) / 1e6:.1f} MB)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
