"""The antalate Bus against raw lcm: round trip at 1 kHz and lossless throughput, two processes.

    .venv/bin/python benchmarks/bus.py [--n 5000] [--seconds 1.5]

Everything runs inside a private network namespace (tests/netns.py), never on the host's network:
the outer process only makes the namespace and prints what the inner one reports.

Round trip: this process publishes a ~97-byte ``telemetry_t`` on PING every millisecond; an echo
process decodes it and publishes it back on PONG; the time runs from just before the ping is encoded
to the moment the pong handler has the decoded message. Raw lcm: one ``lcm.LCM`` per process, the
handler calls ``telemetry_t.decode``, the main thread runs ``handle_timeout``. Bus: ``Bus.publish`` /
``Bus.subscribe`` with the type, handlers on the Bus's dispatcher thread.

Throughput: this process streams messages at a fixed rate (busy-paced, so evenly spaced) to a sink
process that decodes and counts them; a rate is lossless when the sink counted every message. Burst:
``--burst`` messages back to back at the publisher's full speed. Both sides use the same URL (with
``recv_buf_size``) and the same subscription queue capacity (the Bus's default).

Figures only: nothing here is a timed assertion (DESIGN §12).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

import lcm  # noqa: E402

from antalate_lcm.bus import DEFAULT_QUEUE_CAPACITY, Bus  # noqa: E402
from antalate_lcm.msgs import header_t, telemetry_t  # noqa: E402

URL = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304"
TIME_LIMIT = 85.0  # seconds for the whole run, namespace included
RATES = (10_000, 20_000, 30_000, 40_000, 50_000, 60_000, 70_000, 80_000, 100_000, 120_000, 150_000)
TARGETS = {"p50 ratio": 1.15, "p99 bus us": 1000.0, "throughput ratio": 0.8}


def make_msg() -> telemetry_t:
    msg = telemetry_t()
    msg.header = header_t()
    msg.header.utime = 1_763_836_800_000_000
    msg.header.agent = "swarm-alpha-0001"
    msg.lat, msg.lon, msg.alt, msg.heading = 32.7767, 35.0231, 30.0, 90.0
    msg.vn, msg.ve, msg.vd, msg.battery = 1.0, 0.5, 0.0, 87.5
    msg.armed, msg.in_air, msg.mode = True, True, "GUIDED_NOGPS"
    return msg


# -- the other process -----------------------------------------------------------------------------


class Peer:
    """One side of a benchmark in its own process: ``echo`` (PING -> PONG) or ``sink`` (counts FLOOD)."""

    def __init__(self, api: str, role: str, url: str) -> None:
        self.count = 0
        self.api = api
        self.stop = threading.Event()
        if api == "bus":
            self.bus = Bus({"b": url})
            if role == "echo":
                self.bus.subscribe("b", "PING", telemetry_t, lambda _ch, m: self.bus.publish("b", "PONG", m))
            else:
                self.bus.subscribe("b", "FLOOD", telemetry_t, self._count_bus)
            self.bus.open()
        else:
            self.lc = lcm.LCM(url)
            if role == "echo":
                sub = self.lc.subscribe("PING", self._echo_raw)
            else:
                sub = self.lc.subscribe("FLOOD", self._count_raw)
            sub.set_queue_capacity(DEFAULT_QUEUE_CAPACITY)
            threading.Thread(target=self._loop_raw, daemon=True).start()

    def _echo_raw(self, _channel: str, data: bytes) -> None:
        self.lc.publish("PONG", telemetry_t.decode(data).encode())

    def _count_raw(self, _channel: str, data: bytes) -> None:
        telemetry_t.decode(data)
        self.count += 1

    def _count_bus(self, _channel: str, _msg: Any) -> None:
        self.count += 1

    def _loop_raw(self) -> None:
        while not self.stop.is_set():
            self.lc.handle_timeout(100)

    def quiet_count(self, quiet: float = 0.25, limit: float = 10.0) -> int:
        """The count once nothing has arrived for ``quiet`` seconds (the queues have drained)."""
        deadline = time.monotonic() + limit
        last = -1
        while self.count != last and time.monotonic() < deadline:
            last = self.count
            time.sleep(quiet)
        return self.count

    def serve(self) -> None:
        print("ready", flush=True)
        for line in sys.stdin:
            cmd = line.strip()
            if cmd == "count":
                print(self.quiet_count(), flush=True)
            elif cmd == "reset":
                self.quiet_count()
                self.count = 0
                print("ok", flush=True)
        self.stop.set()
        if self.api == "bus":
            self.bus.close()


@contextlib.contextmanager
def peer(api: str, role: str) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen(
        [sys.executable, __file__, "--peer", api, role],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().strip()
        if line != "ready":
            raise RuntimeError(f"{api} {role} did not start (said {line!r})")
        yield proc
    finally:
        if proc.stdin is not None:
            proc.stdin.close()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def ask(proc: subprocess.Popen[str], cmd: str) -> str:
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write(cmd + "\n")
    proc.stdin.flush()
    return proc.stdout.readline().strip()


# -- this process: round trip ----------------------------------------------------------------------


class RawPinger:
    def __init__(self) -> None:
        self.lc = lcm.LCM(URL)
        self.got: tuple[int, int] = (-1, 0)
        self.lc.subscribe("PONG", self._on_pong).set_queue_capacity(DEFAULT_QUEUE_CAPACITY)

    def _on_pong(self, _channel: str, data: bytes) -> None:
        t = time.perf_counter_ns()
        self.got = (telemetry_t.decode(data).header.seq, t)

    def ping(self, msg: telemetry_t, timeout: float) -> int | None:
        seq = msg.header.seq
        t0 = time.perf_counter_ns()
        self.lc.publish("PING", msg.encode())
        deadline = time.monotonic() + timeout
        while self.got[0] != seq:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.lc.handle_timeout(max(1, int(left * 1000)))
        return self.got[1] - t0

    def close(self) -> None:
        del self.lc


class BusPinger:
    def __init__(self) -> None:
        self.bus = Bus({"b": URL})
        self.got: tuple[int, int] = (-1, 0)
        self.event = threading.Event()
        self.bus.subscribe("b", "PONG", telemetry_t, self._on_pong)
        self.bus.open()

    def _on_pong(self, _channel: str, msg: telemetry_t) -> None:
        self.got = (msg.header.seq, time.perf_counter_ns())
        self.event.set()

    def ping(self, msg: telemetry_t, timeout: float) -> int | None:
        seq = msg.header.seq
        self.event.clear()
        t0 = time.perf_counter_ns()
        self.bus.publish("b", "PING", msg)
        deadline = time.monotonic() + timeout
        while self.got[0] != seq:
            left = deadline - time.monotonic()
            if left <= 0 or not self.event.wait(left):
                return None
            self.event.clear()
        return self.got[1] - t0

    def close(self) -> None:
        self.bus.close()


def round_trip(api: str, n: int, period: float = 0.001, warmup: int = 200) -> dict[str, Any]:
    msg = make_msg()
    pinger: RawPinger | BusPinger = RawPinger() if api == "raw" else BusPinger()
    rtts: list[int] = []
    lost = 0
    try:
        with peer(api, "echo"):
            # the echo's group membership takes a moment: ping until it answers
            deadline = time.monotonic() + 5
            while pinger.ping(msg, 0.05) is None:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{api} echo never answered")
            next_t = time.perf_counter()
            for i in range(warmup + n):
                next_t += period
                msg.header.seq = i + 1
                rtt = pinger.ping(msg, 0.1)
                if i >= warmup:
                    if rtt is None:
                        lost += 1
                    else:
                        rtts.append(rtt)
                pause = next_t - time.perf_counter()
                if pause > 0:
                    time.sleep(pause)
                else:
                    next_t = time.perf_counter()  # fell behind: do not send a catch-up burst
    finally:
        pinger.close()
    rtts.sort()
    us = [t / 1000 for t in rtts]
    return {
        "api": api,
        "n": len(us),
        "lost": lost,
        "p50": pct(us, 50),
        "p90": pct(us, 90),
        "p99": pct(us, 99),
        "max": us[-1] if us else float("nan"),
        "mean": statistics.fmean(us) if us else float("nan"),
    }


def pct(sorted_values: list[float], p: float) -> float:
    if not sorted_values:
        return float("nan")
    k = min(len(sorted_values) - 1, max(0, round(p / 100 * len(sorted_values)) - 1))
    return sorted_values[k]


# -- this process: throughput ----------------------------------------------------------------------


def publisher(api: str) -> tuple[Callable[[telemetry_t], object], Callable[[], None]]:
    if api == "raw":
        lc = lcm.LCM(URL)
        return (lambda m: lc.publish("FLOOD", m.encode())), (lambda: None)
    bus = Bus({"b": URL})
    bus.open()
    return (lambda m: bus.publish("b", "FLOOD", m)), bus.close


def stream(send: Callable[[telemetry_t], object], n: int, rate: float | None) -> float:
    """Send ``n`` messages evenly spaced at ``rate`` per second (None: back to back); the rate achieved."""
    msg = make_msg()
    clock = time.perf_counter
    start = clock()
    for i in range(n):
        msg.header.seq = i
        send(msg)
        if rate is not None:
            due = start + (i + 1) / rate
            while clock() < due:
                pass
    return n / (clock() - start)


def throughput(api: str, seconds: float, burst: int, deadline: float) -> dict[str, Any]:
    send, close = publisher(api)
    out: dict[str, Any] = {"api": api, "rates": []}
    try:
        with peer(api, "sink") as sink:
            for _ in range(50):  # until the sink's group membership is in place
                stream(send, 1, None)
                time.sleep(0.02)
                if int(ask(sink, "count")) > 0:
                    break
            ask(sink, "reset")
            achieved = stream(send, burst, None)
            got = int(ask(sink, "count"))
            out["burst"] = {"n": burst, "received": got, "rate": achieved}
            best = 0.0
            for rate in RATES:
                if time.monotonic() + seconds + 1.5 > deadline:
                    out["cut_short"] = True
                    break
                ask(sink, "reset")
                n = int(rate * seconds)
                achieved = stream(send, n, rate)
                got = int(ask(sink, "count"))
                out["rates"].append({"rate": rate, "achieved": achieved, "n": n, "received": got})
                if got < n:
                    break
                best = max(best, achieved)
                if achieved < 0.97 * rate:
                    out["publisher_bound"] = True  # the publisher itself cannot go faster
                    break
            out["lossless"] = best
    finally:
        close()
    return out


# -- orchestration ---------------------------------------------------------------------------------


def inside(args: argparse.Namespace) -> int:
    start = time.monotonic()
    deadline = start + TIME_LIMIT - 8
    size = len(make_msg().encode())
    print(f"message: telemetry_t, {size} bytes encoded; URL {URL}; queue capacity {DEFAULT_QUEUE_CAPACITY}")
    print(f"round trip: {args.n} pings at {1 / 0.001:.0f} Hz after 200 warm-up, ping and echo in two processes")
    rt = {}
    for api in ("raw", "bus") if args.only in (None, "latency") else ():
        r = rt[api] = round_trip(api, args.n)
        print(
            f"  {api:3s}  p50 {r['p50']:7.1f} us  p90 {r['p90']:7.1f} us  p99 {r['p99']:7.1f} us  "
            f"max {r['max']:8.1f} us  mean {r['mean']:7.1f} us  lost {r['lost']}"
        )
    print(f"throughput: sink in another process; streams of {args.seconds:g} s per rate, burst of {args.burst}")
    tp = {}
    for api in ("raw", "bus") if args.only in (None, "throughput") else ():
        t = tp[api] = throughput(api, args.seconds, args.burst, deadline)
        b = t["burst"]
        print(
            f"  {api:3s}  burst {b['received']}/{b['n']} received at {b['rate'] / 1000:.0f}k msg/s;  "
            f"lossless stream up to {t['lossless'] / 1000:.0f}k msg/s"
        )
        for step in t["rates"]:
            print(
                f"         {step['rate'] / 1000:5.0f}k/s asked, {step['achieved'] / 1000:6.1f}k/s sent, "
                f"{step['received']}/{step['n']} received"
            )
        if t.get("publisher_bound"):
            print("         (the publisher, not the sink, was the limit)")
        if t.get("cut_short"):
            print("         (ladder cut short by the time limit)")
    nan = float("nan")
    p50_ratio = rt["bus"]["p50"] / rt["raw"]["p50"] if rt else nan
    p99_bus = rt["bus"]["p99"] if rt else nan
    tp_ratio = tp["bus"]["lossless"] / tp["raw"]["lossless"] if tp and tp["raw"]["lossless"] else nan
    print("against the targets:")
    verdicts = [
        ("p50 bus/raw", p50_ratio, f"<= {TARGETS['p50 ratio']}", p50_ratio <= TARGETS["p50 ratio"]),
        ("p99 bus (us)", p99_bus, f"<= {TARGETS['p99 bus us']:.0f}", p99_bus <= TARGETS["p99 bus us"]),
        ("throughput bus/raw", tp_ratio, f">= {TARGETS['throughput ratio']}", tp_ratio >= TARGETS["throughput ratio"]),
    ]
    for name, value, target, ok in verdicts:
        print(f"  {name:20s} {value:9.2f}   target {target:8s} {'met' if ok else 'MISSED'}")
    print(f"({time.monotonic() - start:.1f} s)")
    if args.json:
        print(json.dumps({"round_trip": rt, "throughput": tp, "p50_ratio": p50_ratio, "throughput_ratio": tp_ratio}))
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=5000, help="round trips per API (default 5000)")
    parser.add_argument("--seconds", type=float, default=1.5, help="length of each throughput stream")
    parser.add_argument("--burst", type=int, default=10_000, help="messages in the back-to-back burst")
    parser.add_argument("--only", choices=("latency", "throughput"), help="run one half only")
    parser.add_argument("--json", action="store_true", help="also print every figure as one JSON line")
    parser.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--peer", nargs=2, metavar=("API", "ROLE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.peer:
        Peer(args.peer[0], args.peer[1], URL).serve()
        return 0
    if args.inside:
        return inside(args)

    from tests.netns import NetNamespace, netns_unavailable, stop_process

    reason = netns_unavailable()
    if reason:
        print(f"cannot run: no private network namespace: {reason}", file=sys.stderr)
        return 2
    argv = [__file__, "--inside", "--n", str(args.n), "--seconds", str(args.seconds), "--burst", str(args.burst)]
    argv += ["--only", args.only] if args.only else []
    argv += ["--json"] if args.json else []
    with NetNamespace() as ns:
        proc = ns.python(*argv)
        try:
            return proc.wait(TIME_LIMIT)
        except subprocess.TimeoutExpired:
            print(f"benchmark stopped after {TIME_LIMIT:.0f} s", file=sys.stderr)
            stop_process(proc)
            return 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
