"""The antalate Bus against raw lcm: round trip at 1 kHz and lossless throughput, two processes.

    .venv/bin/python benchmarks/bus.py [--n 5000] [--seconds 1.0] [--json]

Everything runs inside a private network namespace (tests/harness/netns.py), never on the host's network:
the outer process only makes the namespace and waits for the inner one, which prints the figures.

Round trip: this process publishes a ~100-byte ``telemetry_t`` on PING every millisecond; an echo
process decodes it and publishes it back on PONG; the time runs from just before the ping is encoded
to the moment the pong handler holds the decoded message. Raw lcm: one ``lcm.LCM`` per process,
subscribed to the one channel, its handler calls ``telemetry_t.decode``, the main thread runs
``handle_timeout``. Bus: ``Buses.publish`` / ``Buses.subscribe(..., telemetry_t, ...)``, handlers on the
loop thread of the Bus's private executor (no Context: the sender is the main thread, which waits on
an Event, so the ping side has one thread hop that ``node`` below does not). The Bus (and so every
node) reads udpm:// from a socket of its own on the loop thread (docs/lan.md, "Who reads a udpm
bus"); raw lcm reads through liblcm's receive thread and notify pipe, one thread wake-up more per
message. The APIs run on separate multicast ports with their echo processes all up,
and take turns in blocks of 100 pings, so load from elsewhere on the machine falls on each alike.

Throughput: this process streams messages at a fixed rate (busy-paced, so evenly spaced) to a sink
process that decodes and counts them. A rate passes when the sink received every message and finished
at most 50 ms after the last was sent (it kept up, rather than filling its queue); the figure is the
highest rate that passes. Burst: ``--burst`` messages back to back at the publisher's full speed. Raw
and Bus use the same URL options (``recv_buf_size``) and subscription queue capacity (the Bus's default).

Before the streams, each publisher sends alone (nobody listening) to show what it can send at most.

The round trip is also measured for ``raw-thread``: raw lcm with a bare Bus's threading on the ping
side (another thread runs the handler while the sender waits), the floor for any design where the
sender is not the thread that handles the answer.

Node to node (``node``): a :class:`~antalate_lcm.core.node.Node` in each process, through the real
executor path: ``Node.publish`` of TELEMETRY (header stamped), ``Node.subscribe`` (decode, input
validation, then the handler on the executor's loop thread). The pinger runs on its node's loop (a
coroutine on ``Executor.loop`` publishes and awaits the pong), the echo is a node handler that
publishes back; the time runs from the publish to the pong handler. The sink is a node counting in
its handler; the streaming publisher calls ``Node.publish``.

``--stages`` times where a raw and a node round trip go (the echo reports its own stamps; one
host, so the processes share CLOCK_MONOTONIC): the ping's send call, from its return to the echo's
handler, the echo's send, and from that to the pong handler. A send call returns only after the
kernel has queued the datagram and woken the reader (which often runs first, on the sender's core:
a synchronous wake-up), so the second stage can be negative. ``--busy`` spins a second process on
the other core for the whole run; ``--tree DIR`` runs antalate (this process and the peers) from
another checkout, a baseline in the same session; ``--apis`` measures only some APIs beside raw lcm.

Issue 32 (2026-11-27, 2 cores, load 4-7 from other work, >= 3 runs each): node/raw p50 0.63-0.92
quiet and 0.76-1.03 with ``--busy``, this tree and the one before alike; p99 165 us to 5.8 ms for raw
and node alike, the tail all in the reader waiting for a core ("to echo handler" p99 up to 3.7 ms
while the handler's own work stays under 100 us). ``--stages``: a send call is 30-58 us of wall time
for both (the kernel delivers the looped-back copy and wakes the reader inside it; about 4 us of it
is the sender's CPU); a node spends less in its sends (echo send 12-27 us against raw's 30-43: no
lcm-gen encode, no liblcm publish) and more on receiving (to pong handler 13-20 us: wake, read,
parse, decode, deliver in Python, against raw's 3-12 us, where liblcm's thread has often run inside
the echo's send call). The 1.15-1.18x of the issue (2026-11-25): that tree (3616f4f) published
through lcm-gen and liblcm, its sends 4-8 us longer, and measured 1.01x quiet and 0.91x busy beside
this tree's 0.80x and 0.90x in the same session; and the ratio moves by +-0.15 between runs at one
load, as the scheduler places the readers. No GIL contention shows: the node's receive stays
13-20 us at p50 with a second process busy.

Signing (docs/security.md): ``bus-signed`` is the Bus with what a node does under a swarm key on
every message, in the same run: the sender stamps ``header.utime`` and signs (HMAC-SHA256 into
``header.mac``), the receiver runs the node's :class:`~antalate_lcm.wire.security.Authenticator` (MAC,
window, replay guard) before counting or echoing; the echo re-stamps and re-signs its pong. So one
round trip holds two signatures and two checks. The cost of one ``sign`` and one check is also timed
alone, in this process. Takes about 140 s; never more than 190 s. Figures only: nothing here is a
timed assertion (docs/design.md §12).

Zenoh (``zenoh``, docs/wan.md): the same Bus on a ``zenoh://`` URL, client mode, through an
``antalate router`` process on loopback (so every message crosses two TCP links and the router), in
the same run as udpm and raw lcm. Targets: p50 at most 2x the Bus on udpm, 50k msg/s lossless.

Zenoh with mutual TLS (``zenoh-tls``, issue 29): the same again through a second ``antalate router``
with ``--tls-cert --tls-key --ca`` (a CA from ``antalate lab-ca``, a client certificate per
process), so the cost of TLS on the router path stands beside plain TCP in the same run. Both routers
run their default access control (keys under ``antalate`` only).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import math
import os
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

#: The checkout whose antalate runs here and in the peers (``--tree``: a baseline in the same session).
TREE_ENV = "ANTALATE_BENCH_TREE"
REPO = Path(os.environ.get(TREE_ENV) or Path(__file__).resolve().parent.parent).resolve()
for _p in (str(Path(__file__).resolve().parent), str(REPO)):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import logging  # noqa: E402

import lcm  # noqa: E402

from antalate_lcm.core.bus import DEFAULT_QUEUE_CAPACITY  # noqa: E402
from antalate_lcm.msgs import header_t, telemetry_t  # noqa: E402
from antalate_lcm.wire.security import Authenticator, SecurityPolicy, signed_bytes  # noqa: E402

PORTS = {"raw": 7667, "bus": 7668, "raw-thread": 7670, "bus-signed": 7671, "node": 7672}
BUS_MODULES = {"bus": "antalate_lcm.core.bus", "bus-signed": "antalate_lcm.core.bus"}
SWARM_KEY = "benchmark-swarm-key-0123456789abcdef"
TIME_LIMIT = 190.0  # seconds for the whole run, namespace included
RATES = (10_000, 20_000, 30_000, 40_000, 50_000, 60_000, 80_000, 100_000, 120_000, 150_000)
KEEP_UP = 0.05  # s: the sink must finish this soon after the last message was sent
BLOCK = 100  # pings per turn
TARGETS = {"p50 ratio": 1.15, "p99 bus us": 1000.0, "throughput ratio": 0.8}
#: Node to node (issue 15): at raw lcm's latency, and most of its throughput.
NODE_TARGETS = {"p50 ratio": 1.05, "p99 bus us": 1000.0, "throughput ratio": 0.9}


# zenoh:// through a router on loopback (docs/wan.md): the Bus over Zenoh, next to udpm.
PORTS["zenoh"] = 7673
BUS_MODULES["zenoh"] = "antalate_lcm.core.bus"
ZENOH_TARGETS = {"p50 ratio to bus": 2.0, "throughput": 50_000.0}
PORTS["zenoh-tls"] = 7674
BUS_MODULES["zenoh-tls"] = "antalate_lcm.core.bus"
#: Where the run's lab CA is (set by the inner process before the peers start; they inherit it).
PKI_ENV = "ANTALATE_BENCH_PKI"
#: Set (by ``--stages``) for the echo peers: they time each echo (handler entered, send returned).
STAGES_ENV = "ANTALATE_BENCH_STAGES"


def url(api: str) -> str:
    if api == "zenoh":
        return f"zenoh://?connect=tcp/127.0.0.1:{PORTS['zenoh']}&mode=client"
    if api == "zenoh-tls":
        pki = Path(os.environ[PKI_ENV])
        return (
            f"zenoh://?connect=tls/127.0.0.1:{PORTS['zenoh-tls']}&mode=client&ca={pki / 'ca.pem'}"
            f"&cert={pki / 'bench.pem'}&cert_key={pki / 'bench.key'}"
        )
    return f"udpm://239.255.76.67:{PORTS[api]}?ttl=0&recv_buf_size=4194304"


def busy_loop(stop_at: float) -> None:
    """The --busy process: pure Python arithmetic until ``stop_at`` (monotonic), on the other core."""
    x = 0
    while time.monotonic() < stop_at:
        for i in range(10_000):
            x = (x * 31 + i) % 1_000_003


def bus_class(api: str) -> Any:
    return importlib.import_module(BUS_MODULES[api]).Buses


def make_msg() -> telemetry_t:
    msg = telemetry_t()
    msg.header = header_t()
    msg.header.utime = 1_763_836_800_000_000
    msg.header.agent = "swarm-alpha-0001"
    msg.lat, msg.lon, msg.alt, msg.heading = 32.7767, 35.0231, 30.0, 90.0
    msg.vn, msg.ve, msg.vd, msg.battery = 1.0, 0.5, 0.0, 87.5
    msg.armed, msg.in_air, msg.mode = True, True, "GUIDED_NOGPS"
    return msg


class Signer:
    """What ``Node.publish`` does under a swarm key: a strictly increasing utime, then the signed bytes."""

    def __init__(self) -> None:
        self.last = 0

    def __call__(self, msg: telemetry_t) -> bytes:
        self.last = max(int(time.time() * 1e6), self.last + 1)
        msg.header.utime = self.last
        return signed_bytes(msg, SWARM_KEY)


def checker() -> Authenticator:
    """What ``Node.subscribe`` runs on every message under a swarm key (MAC, window, replay guard)."""
    return Authenticator(SecurityPolicy(SWARM_KEY, (), 5.0), logging.getLogger("benchmark"))


def make_node(agent: str, api: str = "node") -> Any:
    """A bare node (no key: unsigned like raw lcm) with its own context, its loop running."""
    from antalate_lcm.core.config import parse_config
    from antalate_lcm.core.node import Context, Node, NodeSettings

    # insecure: TELEMETRY is an agent-internal topic, and this compares transports, not keys
    config = parse_config(
        {"agent": {"name": agent}, "buses": {"lan": url(api)}, "security": {"insecure": True}}
    )
    context = Context.create(config)
    buses = getattr(context, "buses", None)  # None: a --tree checkout from before issue 26 named it `bus`
    (context.bus if buses is None else buses).open()
    context.executor.start()
    node = Node(NodeSettings.from_config(config), context, name="bench")
    node.start()
    return node


# -- the other process -----------------------------------------------------------------------------


class Peer:
    """One side of a benchmark in its own process: ``echo`` (PING -> PONG) or ``sink`` (counts FLOOD)."""

    def __init__(self, api: str, role: str) -> None:
        self.count = 0
        self.last = 0.0
        self.api = api
        self.stop = threading.Event()
        #: seq -> (handler entered, send returned), ns (--stages: raw and node echoes only).
        self.stamps: dict[int, tuple[int, int]] | None = {} if os.environ.get(STAGES_ENV) else None
        if api == "node":
            self.node = make_node("echo" if role == "echo" else "sink")
            if role == "echo":
                self.node.context.executor.run_sync(
                    lambda: self.node.subscribe("TELEMETRY", self._echo_node, agent="pinger")
                )
            else:
                self.node.context.executor.run_sync(
                    lambda: self.node.subscribe("TELEMETRY", self._count_node, agent="source")
                )
        elif api.startswith("raw"):
            self.lc = lcm.LCM(url(api))
            if role == "echo":
                sub = self.lc.subscribe("PING", self._echo_raw)
            else:
                sub = self.lc.subscribe("FLOOD", self._count_raw)
            sub.set_queue_capacity(DEFAULT_QUEUE_CAPACITY)
            threading.Thread(target=self._loop_raw, daemon=True).start()
        else:
            self.bus = bus_class(api)({"b": url(api)})
            signed = api.endswith("-signed")
            self.sign, self.auth = Signer(), checker()
            if role == "echo":
                echo = self._echo_signed if signed else (lambda _ch, m: self.bus.publish("b", "PONG", m))
                self.bus.subscribe("b", "PING", telemetry_t, echo)
            else:
                self.bus.subscribe(
                    "b", "FLOOD", telemetry_t, self._count_signed if signed else self._count_bus
                )
            self.bus.open()

    def _echo_node(self, msg: telemetry_t) -> None:
        if self.stamps is None:
            self.node.publish("TELEMETRY", msg, seq=msg.header.seq)
            return
        t = time.perf_counter_ns()
        self.node.publish("TELEMETRY", msg, seq=msg.header.seq)
        self.stamps[msg.header.seq] = (t, time.perf_counter_ns())

    def _count_node(self, _msg: telemetry_t) -> None:
        self.count += 1
        self.last = time.perf_counter()

    def _echo_signed(self, channel: str, msg: telemetry_t) -> None:
        if self.auth.check(msg, channel) is None:
            self.bus.publish("b", "PONG", self.sign(msg))

    def _count_signed(self, channel: str, msg: telemetry_t) -> None:
        if self.auth.check(msg, channel) is None:
            self.count += 1
            self.last = time.perf_counter()

    def _echo_raw(self, _channel: str, data: bytes) -> None:
        if self.stamps is None:
            self.lc.publish("PONG", telemetry_t.decode(data).encode())
            return
        t = time.perf_counter_ns()
        msg = telemetry_t.decode(data)
        self.lc.publish("PONG", msg.encode())
        self.stamps[msg.header.seq] = (t, time.perf_counter_ns())

    def _count_raw(self, _channel: str, data: bytes) -> None:
        telemetry_t.decode(data)
        self.count += 1
        self.last = time.perf_counter()

    def _count_bus(self, _channel: str, _msg: Any) -> None:
        self.count += 1
        self.last = time.perf_counter()

    def _loop_raw(self) -> None:
        while not self.stop.is_set():
            self.lc.handle_timeout(100)

    def quiet_count(self, quiet: float = 0.15, limit: float = 10.0) -> int:
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
                print(json.dumps([self.quiet_count(), self.last]), flush=True)
            elif cmd == "reset":
                self.quiet_count()
                self.count = 0
                print(json.dumps("ok"), flush=True)
            elif cmd == "stamps":
                print(json.dumps(self.stamps), flush=True)
        self.stop.set()
        if self.api == "node":
            self.node.stop()
            self.node.context.close()
        elif not self.api.startswith("raw"):
            self.bus.close()


@contextlib.contextmanager
def peers(apis: list[str], role: str) -> Iterator[dict[str, subprocess.Popen[str]]]:
    procs: dict[str, subprocess.Popen[str]] = {}
    try:
        for api in apis:
            procs[api] = subprocess.Popen(
                [sys.executable, __file__, "--peer", api, role],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
        for api, proc in procs.items():
            assert proc.stdout is not None
            line = proc.stdout.readline().strip()
            if line != "ready":
                raise RuntimeError(f"{api} {role} did not start (said {line!r})")
        yield procs
    finally:
        for proc in procs.values():
            if proc.stdin is not None:
                proc.stdin.close()
        for proc in procs.values():
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()


def ask(proc: subprocess.Popen[str], cmd: str) -> Any:
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write(cmd + "\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


# -- this process: round trip ----------------------------------------------------------------------


class RawPinger:
    def __init__(self, api: str) -> None:
        self.lc = lcm.LCM(url(api))
        self.got: tuple[int, int] = (-1, 0)
        #: seq -> (ping encoded from, its send returned, pong handler entered), ns (--stages).
        self.stages: dict[int, tuple[int, int, int]] | None = {} if os.environ.get(STAGES_ENV) else None
        self.lc.subscribe("PONG", self._on_pong).set_queue_capacity(DEFAULT_QUEUE_CAPACITY)

    def _on_pong(self, _channel: str, data: bytes) -> None:
        t = time.perf_counter_ns()
        self.got = (telemetry_t.decode(data).header.seq, t)

    def ping(self, msg: telemetry_t, timeout: float) -> int | None:
        seq = msg.header.seq
        t0 = time.perf_counter_ns()
        self.lc.publish("PING", msg.encode())
        sent = time.perf_counter_ns()
        deadline = time.monotonic() + timeout
        while self.got[0] != seq:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.lc.handle_timeout(max(1, int(left * 1000)))
        if self.stages is not None:
            self.stages[seq] = (t0, sent, self.got[1])
        return self.got[1] - t0

    def close(self) -> None:
        del self.lc


class RawThreadPinger:
    """Raw lcm with the Bus's threading: a dispatcher thread runs the handler, the sender waits on an Event."""

    def __init__(self, api: str) -> None:
        self.lc = lcm.LCM(url(api))
        self.got: tuple[int, int] = (-1, 0)
        self.event = threading.Event()
        self.stop = threading.Event()
        self.lc.subscribe("PONG", self._on_pong).set_queue_capacity(DEFAULT_QUEUE_CAPACITY)
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while not self.stop.is_set():
            self.lc.handle_timeout(100)

    def _on_pong(self, _channel: str, data: bytes) -> None:
        msg = telemetry_t.decode(data)
        self.got = (msg.header.seq, time.perf_counter_ns())
        self.event.set()

    def ping(self, msg: telemetry_t, timeout: float) -> int | None:
        seq = msg.header.seq
        self.event.clear()
        t0 = time.perf_counter_ns()
        self.lc.publish("PING", msg.encode())
        deadline = time.monotonic() + timeout
        while self.got[0] != seq:
            left = deadline - time.monotonic()
            if left <= 0 or not self.event.wait(left):
                return None
            self.event.clear()
        return self.got[1] - t0

    def close(self) -> None:
        self.stop.set()
        self.thread.join()


class BusPinger:
    def __init__(self, api: str) -> None:
        self.bus = bus_class(api)({"b": url(api)})
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


class SignedBusPinger(BusPinger):
    """The Bus as a node uses it under a swarm key: sign the ping, check the pong."""

    def __init__(self, api: str) -> None:
        self.sign, self.auth = Signer(), checker()
        super().__init__(api)

    def _on_pong(self, channel: str, msg: telemetry_t) -> None:
        if self.auth.check(msg, channel) is None:
            super()._on_pong(channel, msg)

    def ping(self, msg: telemetry_t, timeout: float) -> int | None:
        seq = msg.header.seq
        self.event.clear()
        t0 = time.perf_counter_ns()
        self.bus.publish("b", "PING", self.sign(msg))
        deadline = time.monotonic() + timeout
        while self.got[0] != seq:
            left = deadline - time.monotonic()
            if left <= 0 or not self.event.wait(left):
                return None
            self.event.clear()
        return self.got[1] - t0


class NodePinger:
    """A node pinging a node: the ping is published from the pinger node's executor thread and the time
    runs to its pong handler there (the main thread only paces the pings and waits for the answer)."""

    def __init__(self, api: str) -> None:
        self.node = make_node("pinger")
        self.ex = self.node.context.executor
        self.got: tuple[int, int] = (-1, 0)
        self.t0 = self.sent = 0
        self.stages: dict[int, tuple[int, int, int]] | None = {} if os.environ.get(STAGES_ENV) else None
        self.event = threading.Event()
        self.ex.run_sync(lambda: self.node.subscribe("TELEMETRY", self._on_pong, agent="echo"))

    def _send(self, msg: telemetry_t) -> None:
        self.t0 = time.perf_counter_ns()
        self.node.publish("TELEMETRY", msg, seq=msg.header.seq)
        self.sent = time.perf_counter_ns()

    def _on_pong(self, msg: telemetry_t) -> None:
        self.got = (msg.header.seq, time.perf_counter_ns())
        self.event.set()

    def ping(self, msg: telemetry_t, timeout: float) -> int | None:
        seq = msg.header.seq
        self.event.clear()
        self.ex.call_soon(self._send, msg)
        deadline = time.monotonic() + timeout
        while self.got[0] != seq:
            left = deadline - time.monotonic()
            if left <= 0 or not self.event.wait(left):
                return None
            self.event.clear()
        if self.stages is not None:
            self.stages[seq] = (self.t0, self.sent, self.got[1])
        return self.got[1] - self.t0

    def close(self) -> None:
        self.node.stop()
        self.node.context.close()


def signing_cost(n: int = 20_000) -> dict[str, float]:
    """Microseconds a signature adds to an encode, and one full check of a decoded telemetry_t, alone."""
    signer, auth, msgs = Signer(), checker(), []
    plain = [make_msg() for _ in range(n)]
    t0 = time.perf_counter()
    for m in plain:
        m.encode()
    t_encode = time.perf_counter() - t0
    t0 = time.perf_counter()
    for m in plain:
        msgs.append(signer(m))
    t1 = time.perf_counter()
    decoded = [telemetry_t.decode(d) for d in msgs]
    t2 = time.perf_counter()
    ok = sum(auth.check(m, "BENCH") is None for m in decoded)
    t3 = time.perf_counter()
    assert ok == n, f"{n - ok} of the benchmark's own messages were rejected"
    # sign: what signing adds to the encode every publish does anyway
    return {"sign_us": (t1 - t0 - t_encode) / n * 1e6, "check_us": (t3 - t2) / n * 1e6}


def round_trip(apis: list[str], n: int, period: float = 0.001, warmup: int = 20) -> dict[str, dict[str, Any]]:
    """``n`` round trips per API at one per ``period``, the APIs taking turns in blocks of BLOCK."""
    msg = make_msg()
    kinds: dict[str, Any] = {
        "raw": RawPinger,
        "raw-thread": RawThreadPinger,
        "bus-signed": SignedBusPinger,
        "node": NodePinger,
    }
    pingers = {api: kinds.get(api, BusPinger)(api) for api in apis}
    rtts: dict[str, list[int]] = {api: [] for api in apis}
    lost = dict.fromkeys(apis, 0)
    measured: set[int] = set()
    stages: dict[str, dict[str, list[float]]] = {}
    seq = 0
    try:
        with peers(apis, "echo") as echoes:
            for api, pinger in pingers.items():  # group membership takes a moment: ping until answered
                deadline = time.monotonic() + 5
                while True:
                    seq += 1
                    msg.header.seq = seq
                    if pinger.ping(msg, 0.05) is not None:
                        break
                    if time.monotonic() > deadline:
                        raise RuntimeError(f"{api} echo never answered")
            for turn in range((n + BLOCK - 1) // BLOCK):
                for api in apis if turn % 2 == 0 else apis[::-1]:
                    pinger = pingers[api]
                    next_t = time.perf_counter()
                    for i in range(warmup + min(BLOCK, n - turn * BLOCK)):
                        next_t += period
                        seq += 1
                        msg.header.seq = seq
                        rtt = pinger.ping(msg, 0.1)
                        if i >= warmup:  # the first pings of a turn wake caches and threads
                            if rtt is None:
                                lost[api] += 1
                            else:
                                rtts[api].append(rtt)
                                measured.add(seq)
                        pause = next_t - time.perf_counter()
                        if pause > 0:
                            time.sleep(pause)
                        else:
                            next_t = time.perf_counter()  # fell behind: no catch-up burst
            for api, pinger in pingers.items():
                mine = getattr(pinger, "stages", None)
                if mine is not None:
                    theirs = {int(k): v for k, v in ask(echoes[api], "stamps").items()}
                    stages[api] = stage_times(mine, theirs, measured)
    finally:
        for pinger in pingers.values():
            pinger.close()
    out: dict[str, dict[str, Any]] = {}
    for api in apis:
        us = sorted(t / 1000 for t in rtts[api])
        out[api] = {
            "n": len(us),
            "lost": lost[api],
            "p50": pct(us, 50),
            "p90": pct(us, 90),
            "p99": pct(us, 99),
            "max": us[-1] if us else float("nan"),
            "mean": statistics.fmean(us) if us else float("nan"),
        }
        if api in stages:
            out[api]["stages"] = {
                name: {"p50": pct(v, 50), "p90": pct(v, 90), "p99": pct(v, 99)}
                for name, v in stages[api].items()
            }
    return out


#: The stages of a round trip (``--stages``), from the pinger's and the echo's clocks (one host:
#: CLOCK_MONOTONIC is shared by the processes).
STAGES = (
    "ping send",  # encode (node: stamp, encode) and the send call, until it returned
    "to echo handler",  # the echo wakes, reads, (node: decodes and checks) and enters its handler
    "echo send",  # the echo's publish until it returned (raw: with its decode)
    "to pong handler",  # the pinger wakes, reads and decodes: its handler holds the pong
)


def stage_times(
    pinger: dict[int, tuple[int, int, int]], echo: dict[int, tuple[int, int]], measured: set[int]
) -> dict[str, list[float]]:
    """Each stage's sorted durations (us) over the measured pings both sides timed. A send call
    returns after the kernel has queued the datagram and woken the reader, which may already run
    on the other core: "to echo handler" can be negative."""
    out: dict[str, list[float]] = {name: [] for name in STAGES}
    for seq, (t0, sent, pong) in pinger.items():
        e = echo.get(seq)
        if seq not in measured or e is None:
            continue
        for name, (a, b) in zip(STAGES, ((t0, sent), (sent, e[0]), e, (e[1], pong)), strict=True):
            out[name].append((b - a) / 1000)
    return {name: sorted(v) for name, v in out.items()}


def pct(sorted_values: list[float], p: float) -> float:
    if not sorted_values:
        return float("nan")
    k = min(len(sorted_values) - 1, max(0, round(p / 100 * len(sorted_values)) - 1))
    return sorted_values[k]


# -- this process: throughput ----------------------------------------------------------------------


def publisher(api: str) -> tuple[Callable[[telemetry_t], object], Callable[[], None]]:
    if api == "raw":
        lc = lcm.LCM(url(api))
        return (lambda m: lc.publish("FLOOD", m.encode())), (lambda: None)
    if api == "node":
        node = make_node("source")

        def close() -> None:
            node.stop()
            node.context.close()

        return (lambda m: node.publish("TELEMETRY", m)), close
    bus = bus_class(api)({"b": url(api)})
    bus.open()
    if api.endswith("-signed"):
        signer = Signer()
        return (lambda m: bus.publish("b", "FLOOD", signer(m))), bus.close
    return (lambda m: bus.publish("b", "FLOOD", m)), bus.close


def stream(send: Callable[[telemetry_t], object], n: int, rate: float | None) -> tuple[float, float]:
    """Send ``n`` messages evenly spaced at ``rate`` a second (None: back to back): (rate achieved, end)."""
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
    end = clock()
    return n / (end - start), end


def throughput(apis: list[str], seconds: float, burst: int, deadline: float) -> dict[str, dict[str, Any]]:
    pubs = {api: publisher(api) for api in apis}
    out: dict[str, dict[str, Any]] = {api: {"steps": [], "lossless": 0.0, "alone": 0.0} for api in apis}
    try:
        for _ in range(2):  # the publisher alone, nobody listening: what it can send at most
            for api in apis:
                out[api]["alone"] = max(out[api]["alone"], stream(pubs[api][0], 30_000, None)[0])
        with peers(apis, "sink") as sinks:
            for api in apis:
                for _ in range(100):  # until the sink's group membership is in place
                    stream(pubs[api][0], 1, None)
                    time.sleep(0.02)
                    if ask(sinks[api], "count")[0] > 0:
                        break
                ask(sinks[api], "reset")
                rate, end = stream(pubs[api][0], burst, None)
                got, last = ask(sinks[api], "count")
                out[api]["burst"] = {"n": burst, "received": got, "rate": rate, "drain": max(0.0, last - end)}
            climbing = list(apis)
            for rate in RATES:
                # A rate is tried by every API still climbing or by none (a retry each counted in),
                # so the time limit never gives one API a step that another did not get.
                if time.monotonic() + 2 * len(climbing) * (seconds + 1.0) > deadline:
                    for api in climbing:
                        out[api]["cut_short"] = True
                    break
                for api in list(climbing):
                    n = int(rate * seconds)
                    kept_up = passed = False
                    for attempt in (1, 2):  # one retry: a step can fail because of load from elsewhere
                        ask(sinks[api], "reset")
                        achieved, end = stream(pubs[api][0], n, rate)
                        got, last = ask(sinks[api], "count")
                        step = {
                            "rate": rate,
                            "achieved": achieved,
                            "n": n,
                            "received": got,
                            "lag": last - end,
                        }
                        out[api]["steps"].append({**step, "attempt": attempt})
                        if got == n and last - end <= KEEP_UP:
                            kept_up = True
                            out[api]["lossless"] = max(out[api]["lossless"], achieved)
                            passed = achieved >= 0.97 * rate
                            if passed:
                                break
                    if not passed:
                        if kept_up:
                            out[api]["publisher_bound"] = True  # the publisher, not the sink, was the limit
                        climbing.remove(api)
                if not climbing:
                    break
    finally:
        for _send, close in pubs.values():
            close()
    return out


# -- orchestration ---------------------------------------------------------------------------------


def zenoh_router(api: str = "zenoh") -> subprocess.Popen[str] | None:
    """``antalate router`` on loopback for the zenoh column (``zenoh-tls``: with mutual TLS, a lab CA
    made first); None (column left out) without eclipse-zenoh."""
    try:
        import zenoh  # noqa: F401
    except ImportError:
        print("zenoh: eclipse-zenoh is not installed, no zenoh column (pip install -e '.[zenoh]')")
        return None
    cli = [sys.executable, "-m", "antalate_lcm.cli"]
    listen = ["--listen", f"tcp/127.0.0.1:{PORTS[api]}"]
    if api == "zenoh-tls":
        import tempfile

        pki = Path(tempfile.mkdtemp(prefix="antalate-bench-pki-"))
        subprocess.run([*cli, "lab-ca", str(pki), "--client", "bench"], check=True, capture_output=True)
        os.environ[PKI_ENV] = str(pki)
        listen = ["--listen", f"tls/127.0.0.1:{PORTS[api]}", "--tls-cert", str(pki / "router.pem"),
                  "--tls-key", str(pki / "router.key"), "--ca", str(pki / "ca.pem")]  # fmt: skip
    proc = subprocess.Popen(
        [*cli, "--log-level", "ERROR", "router", *listen],
        stdout=subprocess.PIPE,
        text=True,
        cwd=str(REPO),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if "listening" not in line:
        proc.kill()
        raise RuntimeError(f"antalate router did not start (said {line!r})")
    return proc


def stop_router(proc: subprocess.Popen[str]) -> None:
    proc.terminate()
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


def inside(args: argparse.Namespace) -> int:
    start = time.monotonic()
    deadline = start + TIME_LIMIT - 6
    apis = ["raw", "bus", "bus-signed", "node"]
    latency_apis = ["raw", "bus", "bus-signed", "raw-thread", "node"]
    size = len(make_msg().encode())
    router = tls_router = None
    if args.apis:  # a subset: raw lcm always, as the yardstick
        latency_apis = ["raw", *(a for a in latency_apis if a in args.apis and a != "raw")]
        apis = [a for a in apis if a in latency_apis]
    else:
        router = zenoh_router()
        tls_router = zenoh_router("zenoh-tls") if router is not None else None
    if router is not None and tls_router is not None:
        apis += ["zenoh", "zenoh-tls"]
        latency_apis += ["zenoh", "zenoh-tls"]
    print(
        f"message: telemetry_t, {size} bytes; URL {url('raw')} (one port per API); queue capacity {DEFAULT_QUEUE_CAPACITY}"
    )
    print(
        f"CPUs: {os.cpu_count()}; load average {os.getloadavg()[0]:.2f} at start; antalate from {REPO}"
        f"{'; a second process busy' if args.busy else ''}"
    )
    rt: dict[str, dict[str, Any]] = {}
    if args.only in (None, "latency"):
        print(
            f"round trip: {args.n} pings per API at 1 kHz, in turns of {BLOCK}, ping and echo in two processes"
        )
        rt = round_trip(latency_apis, args.n)
        for api, r in rt.items():
            print(
                f"  {api:10s}  p50 {r['p50']:6.1f} us  p90 {r['p90']:6.1f} us  p99 {r['p99']:7.1f} us  "
                f"max {r['max']:7.1f} us  mean {r['mean']:6.1f} us  lost {r['lost']}"
            )
            for name, st in r.get("stages", {}).items():
                print(
                    f"      {name:16s} p50 {st['p50']:6.1f} us  p90 {st['p90']:6.1f} us  p99 {st['p99']:7.1f} us"
                )
        if "raw-thread" in rt:
            print(
                "  (raw-thread: raw lcm with the Bus's threading on the ping side -- a dispatcher thread runs the "
                f"handler -- p50 {rt['raw-thread']['p50'] / rt['raw']['p50']:.2f}x raw: the floor for any "
                "design with a dispatcher thread)"
            )
    tp: dict[str, dict[str, Any]] = {}
    if args.only in (None, "throughput"):
        print(
            f"throughput: sink in another process; {args.seconds:g} s stream per rate (passes when all received "
            f"and the sink done <= {KEEP_UP * 1000:.0f} ms after the last send); burst of {args.burst}"
        )
        tp = throughput(apis, args.seconds, args.burst, deadline)
        print(
            "  publisher alone, nobody listening: "
            + ", ".join(f"{a} {t['alone'] / 1000:.0f}k" for a, t in tp.items())
        )
        for api, t in tp.items():
            b = t["burst"]
            print(
                f"  {api:10s}  burst {b['received']}/{b['n']} received, sent at {b['rate'] / 1000:.0f}k msg/s, "
                f"drained {b['drain'] * 1000:.0f} ms later;  sustained lossless: {t['lossless'] / 1000:.0f}k msg/s"
            )
            for s in t["steps"]:
                retry = "retry" if s["attempt"] > 1 else ""
                print(
                    f"         {retry:5s}{s['rate'] / 1000:5.0f}k/s asked, {s['achieved'] / 1000:6.1f}k/s sent, "
                    f"{s['received']}/{s['n']} received, sink done {s['lag'] * 1000:+6.0f} ms after the last send"
                )
            if t.get("publisher_bound"):
                print("              (the publisher, not the sink, was the limit)")
            if t.get("cut_short"):
                print("              (ladder cut short by the time limit)")
    nan = float("nan")
    cost = signing_cost()
    print(
        f"signing, alone: sign {cost['sign_us']:.1f} us, check (MAC + window + replay guard) "
        f"{cost['check_us']:.1f} us per message"
    )
    if "bus-signed" in rt and "bus" in rt:
        print(
            f"  round trip p50 signed {rt['bus-signed']['p50']:.1f} us vs unsigned {rt['bus']['p50']:.1f} us "
            f"({rt['bus-signed']['p50'] - rt['bus']['p50']:+.1f} us for two signatures and two checks)"
        )
    if "bus-signed" in tp and "bus" in tp and tp["bus"]["lossless"]:
        print(
            f"  lossless throughput signed {tp['bus-signed']['lossless'] / 1000:.0f}k vs unsigned "
            f"{tp['bus']['lossless'] / 1000:.0f}k msg/s ({tp['bus-signed']['lossless'] / tp['bus']['lossless']:.2f}x)"
        )
    if router is not None and tls_router is not None:
        stop_router(router)
        stop_router(tls_router)
        if rt:
            print(
                f"mutual TLS on the router path: round trip p50 {rt['zenoh-tls']['p50']:.1f} us vs tcp "
                f"{rt['zenoh']['p50']:.1f} us ({rt['zenoh-tls']['p50'] - rt['zenoh']['p50']:+.1f} us), p99 "
                f"{rt['zenoh-tls']['p99']:.1f} vs {rt['zenoh']['p99']:.1f} us"
            )
        if tp and tp["zenoh"]["lossless"]:
            print(
                f"  lossless throughput tls {tp['zenoh-tls']['lossless'] / 1000:.0f}k vs tcp "
                f"{tp['zenoh']['lossless'] / 1000:.0f}k msg/s "
                f"({tp['zenoh-tls']['lossless'] / tp['zenoh']['lossless']:.2f}x); burst "
                f"{tp['zenoh-tls']['burst']['rate'] / 1000:.0f}k vs {tp['zenoh']['burst']['rate'] / 1000:.0f}k msg/s sent"
            )
        p50 = rt["zenoh"]["p50"] / rt["bus"]["p50"] if rt else nan
        lossless = tp["zenoh"]["lossless"] if tp else nan
        print("zenoh (through antalate router on loopback) against its targets:")
        print(
            f"  {'p50 zenoh/bus':22s} {p50:8.2f}   target <= {ZENOH_TARGETS['p50 ratio to bus']:<5} "
            f"{'met' if p50 <= ZENOH_TARGETS['p50 ratio to bus'] else 'MISSED'}"
        )
        print(
            f"  {'throughput zenoh':22s} {lossless / 1000:7.0f}k   target >= {ZENOH_TARGETS['throughput'] / 1000:.0f}k   "
            f"{'met' if lossless >= ZENOH_TARGETS['throughput'] else 'MISSED'}"
        )
    print("against the targets:")
    for api, targets in (("bus", TARGETS), ("node", NODE_TARGETS)):
        if api not in latency_apis:
            continue
        p50_ratio = rt[api]["p50"] / rt["raw"]["p50"] if rt else nan
        p99 = rt[api]["p99"] if rt else nan
        tp_ratio = tp[api]["lossless"] / tp["raw"]["lossless"] if tp and tp["raw"]["lossless"] else nan
        for name, value, target, ok in (
            (f"p50 {api}/raw", p50_ratio, f"<= {targets['p50 ratio']}", p50_ratio <= targets["p50 ratio"]),
            (f"p99 {api} (us)", p99, f"<= {targets['p99 bus us']:.0f}", p99 <= targets["p99 bus us"]),
            (
                f"throughput {api}/raw",
                tp_ratio,
                f">= {targets['throughput ratio']}",
                tp_ratio >= targets["throughput ratio"],
            ),
        ):
            verdict = "not measured" if math.isnan(value) else "met" if ok else "MISSED"  # (--only)
            print(f"  {name:22s} {value:8.2f}   target {target:8s} {verdict}")
    print(f"({time.monotonic() - start:.1f} s; load average {os.getloadavg()[0]:.2f} at the end)")
    if args.json:
        print(json.dumps({"round_trip": rt, "throughput": tp, "signing": cost}))
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--n", type=int, default=5000, help="round trips per API (default 5000)")
    parser.add_argument(
        "--seconds", type=float, default=1.0, help="length of each throughput stream (default 1)"
    )
    parser.add_argument("--burst", type=int, default=10_000, help="messages in the back-to-back burst")
    parser.add_argument("--only", choices=("latency", "throughput"), help="run one half only")
    parser.add_argument("--json", action="store_true", help="also print every figure as one JSON line")
    parser.add_argument(
        "--apis",
        nargs="+",
        choices=("bus", "bus-signed", "raw-thread", "node"),
        help="only these (and raw lcm); no zenoh columns",
    )
    parser.add_argument("--busy", action="store_true", help="a second process spins for the whole run")
    parser.add_argument("--tree", type=Path, help="run antalate from this checkout (a baseline)")
    parser.add_argument(
        "--stages", action="store_true", help="time the round trip's stages too (raw lcm and node)"
    )
    parser.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--peer", nargs=2, metavar=("API", "ROLE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.peer:
        Peer(args.peer[0], args.peer[1]).serve()
        return 0
    if args.inside:
        return inside(args)

    from tests.harness.netns import NetNamespace, netns_unavailable
    from tests.harness.process import stop_process

    reason = netns_unavailable()
    if reason:
        print(f"cannot run: no private network namespace: {reason}", file=sys.stderr)
        return 2
    argv = [
        __file__,
        "--inside",
        "--n",
        str(args.n),
        "--seconds",
        str(args.seconds),
        "--burst",
        str(args.burst),
    ]
    argv += ["--only", args.only] if args.only else []
    argv += ["--json"] if args.json else []
    argv += ["--apis", *args.apis] if args.apis else []
    argv += ["--busy"] if args.busy else []
    env = {TREE_ENV: str(args.tree.resolve())} if args.tree else {}
    if args.stages:
        env[STAGES_ENV] = "1"
    busy = None
    if args.busy:
        import multiprocessing

        busy = multiprocessing.Process(target=busy_loop, args=(time.monotonic() + TIME_LIMIT,), daemon=True)
        busy.start()
    try:
        with NetNamespace() as ns:
            proc = ns.python(*argv, extra_env=env)
            try:
                return proc.wait(TIME_LIMIT)
            except subprocess.TimeoutExpired:
                print(f"benchmark stopped after {TIME_LIMIT:.0f} s", file=sys.stderr)
                stop_process(proc)
                return 1
    finally:
        if busy is not None:
            busy.terminate()


if __name__ == "__main__":
    sys.exit(main())
