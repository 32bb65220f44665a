"""CPU of the operator console with N agents publishing (targets at 5 Hz: < 30 % of one core at 1,000
agents and key -> wire p99 < 50 ms; < 15 % at 200 agents).

    .venv/bin/python benchmarks/tui.py [--agents 200] [--hz 5] [--seconds 20] [--arbiter]

What runs, and why this way:

* a **publisher process** plays N agents: ``mc_state_t``, ``hlc_state_t`` and ``telemetry_t`` (and,
  with ``--arbiter``, ``arbiter_status_t``) at ``--hz`` each, staggered over the period like
  unsynchronised vehicles, flying circles; it acknowledges the console's commands through
  ``last_command_seq`` like an MC would, and records when each command arrived;
* the **console** is the real ``python -m operator_tui CONFIG`` on a pseudo-terminal of
  ``--size`` (a headless Textual app skips writing the screen, which would flatter the figure);
  this script drains the terminal output and presses keys into it;
* both run inside a private network namespace on real UDP multicast (tests/harness/netns.py), so the
  figure includes LCM receive and decode and nothing touches the host network.

The console's CPU is read from /proc/<pid>/stat over the measurement window (after it shows all
agents), so the publisher's and this script's costs are not counted. Key-to-wire latency (a key
written to the terminal until the command arrives at the publisher) shows the UI stayed responsive.

A reference workload (benchmarks/_reference.py, the one benchmarks/agents.py divides by) is measured
in the same run, in the namespace just before the console starts: ``ref`` is the CPU µs one raw-lcm
``telemetry_t`` costs this machine now (encode, publish, decode). The console's CPU per message
received (its CPU share / the publisher's rate) divided by ``ref`` is ``x ref``: what one message
costs the console in raw-lcm messages, a figure that moves much less with the machine than the %.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import math
import os
import pty
import selectors
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

URL = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608"


# ---------------------------------------------------------------------- publisher (child process)
def run_publisher(url: str, agents: int, hz: float, arbiter: bool) -> int:
    """Play ``agents`` vehicles until stdin closes; then print a JSON report on stdout."""
    from antalate_lcm.base.geo import FlatFrame
    from antalate_lcm.core.bus import Buses
    from antalate_lcm.msgs import arbiter_status_t, hlc_state_t, mc_state_t, operator_cmd_t, telemetry_t

    bus = Buses({"lan": url})
    frame = FlatFrame(47.3977, 8.5456)
    names = [f"uav{i:03d}" for i in range(agents)]
    last_seq = dict.fromkeys(names, 0)
    received: list[tuple[float, str, int]] = []

    def on_cmd(channel: str, msg: operator_cmd_t) -> None:
        received.append((time.monotonic(), channel, msg.header.seq))
        for name in [msg.target] if msg.target else names:
            if name in last_seq:
                last_seq[name] = msg.header.seq

    bus.subscribe("lan", r".*OPERATOR_CMD", operator_cmd_t, on_cmd, regex=True)
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()

    mc, hlc, tel, arb = mc_state_t(), hlc_state_t(), telemetry_t(), arbiter_status_t()
    hlc.autopilot, tel.mode, tel.armed, tel.in_air = "sim", "SIM", True, True
    arb.arbiter, arb.state, arb.n, arb.active = "main", "MISSION", 1, ["dovrat_swarm"]
    period = 1.0 / hz
    t0 = time.monotonic()
    due = [t0 + period * i / agents for i in range(agents)]
    published = 0
    seq = 0
    while not stop.is_set():
        now = time.monotonic()
        for i, name in enumerate(names):
            if due[i] > now:
                continue
            due[i] += period
            if due[i] < now:  # fell behind: skip rather than burst
                due[i] = now + period
            seq += 1
            t = now - t0
            ring = 30.0 + 200.0 * (i % 20) / 20
            angle = t * 0.1 + 2 * math.pi * i / agents
            north, east = ring * math.cos(angle) + 40.0 * (i // 20), ring * math.sin(angle)
            tel.lat, tel.lon = frame.to_latlon(north, east)
            tel.heading = (math.degrees(angle) + 90.0) % 360.0
            tel.vn, tel.ve = -3.0 * math.sin(angle), 3.0 * math.cos(angle)
            tel.alt, tel.battery = 20.0 + i % 7, max(0.0, 100.0 - t * 0.05 - i % 30)
            mc.state = mc_state_t.MISSION if i % 10 else mc_state_t.STANDBY
            mc.last_command_seq = last_seq[name]
            hlc.state = hlc_state_t.AIRBORNE if i % 10 else hlc_state_t.READY
            msgs = [("MC_STATE", mc), ("HLC_STATE", hlc), ("TELEMETRY", tel)]
            if arbiter:
                msgs.append(("ARBITER/main", arb))
            for topic, msg in msgs:
                msg.header.agent, msg.header.seq, msg.header.utime = name, seq, int(time.time() * 1e6)
                bus.publish("lan", f"{name}/{topic}", msg.encode())
                published += 1
        time.sleep(max(0.0, min(min(due) - time.monotonic(), 0.005)))
    usage = os.times()
    print(
        json.dumps(
            {
                "published": published,
                "seconds": time.monotonic() - t0,
                "cpu": usage.user + usage.system,
                "received": received,
            }
        ),
        flush=True,
    )
    bus.close()
    return 0


# ---------------------------------------------------------------------- the console on a pty
def cpu_seconds(pid: int, task: int | None = None) -> float:
    """utime + stime of a process (all its threads), or of one of its threads, from /proc, in seconds."""
    path = f"/proc/{pid}/stat" if task is None else f"/proc/{pid}/task/{task}/stat"
    fields = Path(path).read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def thread_cpu(pid: int) -> dict[int, float]:
    """CPU seconds of each thread of a process (the UI thread's id is the pid)."""
    out: dict[int, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            out[int(task.name)] = cpu_seconds(pid, int(task.name))
    return out


class Terminal:
    """A pseudo-terminal whose output is drained (and searched) by a thread, so the app never blocks."""

    def __init__(self, cols: int, rows: int) -> None:
        self.master, self.slave = pty.openpty()
        fcntl.ioctl(self.slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))
        self.bytes = 0
        self._tail = b""
        self._want: bytes | None = None
        self.seen = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def expect(self, needle: bytes) -> threading.Event:
        self.seen.clear()
        self._want = needle
        return self.seen

    def _drain(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.master, selectors.EVENT_READ)
        while not self._stop.is_set():
            if not sel.select(0.2):
                continue
            try:
                data = os.read(self.master, 65536)
            except OSError:
                return
            self.bytes += len(data)
            if self._want is not None:
                window = self._tail + data
                if self._want in window:
                    self.seen.set()
                    self._want = None
                self._tail = window[-256:]

    def press(self, key: str) -> None:
        os.write(self.master, key.encode())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def measure(args: argparse.Namespace, reader: str) -> int:
    """One console run with its udpm:// reader (``own`` or ``liblcm``), figures printed."""
    from antalate_lcm.core.bus import UDPM_READER_ENV
    from tests.harness.netns import NetNamespace
    from tests.harness.process import stop_process

    cols, rows = (int(x) for x in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp, NetNamespace() as ns:
        config = Path(tmp) / "tui.toml"
        config.write_text(f'[buses]\nlan = "{URL}"\n')
        # The yardstick, in this namespace before anything else runs in it (benchmarks/_reference.py).
        ref_proc = ns.python(__file__, "--role", "reference", stdout=subprocess.PIPE)
        ref_out, _ = ref_proc.communicate(timeout=60)
        ref = float(ref_out.strip())
        pub = ns.python(
            __file__,
            "--role",
            "publisher",
            "--agents",
            str(args.agents),
            "--hz",
            str(args.hz),
            *(["--arbiter"] if args.arbiter else []),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        term = Terminal(cols, rows)
        env = dict(os.environ, TERM="xterm-256color", COLORTERM="truecolor", PYTHONPATH=str(REPO))
        env.pop("NO_COLOR", None)
        env.pop("TEXTUAL", None)
        env[UDPM_READER_ENV] = reader
        profile = ["-m", "cProfile", "-o", str(Path(args.profile).resolve())] if args.profile else []
        tui = ns.popen(
            [sys.executable, *profile, "-m", "operator_tui", str(config)],
            stdin=term.slave,
            stdout=term.slave,
            stderr=term.slave,
            env=env,
            text=False,
        )
        try:
            seen = term.expect(f"agents {args.agents}".encode())
            if not seen.wait(60):
                print(
                    f"the console never showed {args.agents} agents (publisher alive: {pub.poll() is None})",
                    file=sys.stderr,
                )
                return 1
            time.sleep(3.0)  # let the first-seen burst (table inserts, event log) settle
            cpu0, t0, out0 = cpu_seconds(tui.pid), time.monotonic(), term.bytes
            threads0 = thread_cpu(tui.pid)
            presses: list[float] = []
            next_key = t0 + 1.0
            keys = ["t", "down", "l", "d", "r", "down"]
            k = 0
            while time.monotonic() - t0 < args.seconds:
                if time.monotonic() >= next_key:
                    key = keys[k % len(keys)]
                    k += 1
                    if key == "down":
                        term.press("\x1b[B")
                    else:
                        presses.append(time.monotonic())
                        term.press(key)
                    next_key += 1.0
                time.sleep(0.01)
            cpu1, t1, out1 = cpu_seconds(tui.pid), time.monotonic(), term.bytes
            threads1 = thread_cpu(tui.pid)
            assert pub.stdin is not None and pub.stdout is not None
            pub.stdin.close()
            report = json.loads(pub.stdout.readline() or "{}")
        finally:
            term.press("q")  # a clean exit (lets --profile write its stats)
            try:
                tui.wait(10)
            except subprocess.TimeoutExpired:
                tui.send_signal(signal.SIGTERM)
            stop_process(tui)
            stop_process(pub)
            term.close()
    share = (cpu1 - cpu0) / (t1 - t0)
    received = [r for r in report.get("received", []) if "OPERATOR_CMD" in r[1]]
    first_arrivals: dict[int, float] = {}
    for at, _, seq in received:
        first_arrivals.setdefault(seq, at)
    arrivals = sorted(first_arrivals.values())
    lat = [min((a - p for a in arrivals if a >= p), default=math.nan) for p in presses]
    lat = [x for x in lat if x < 0.9]  # a press matched to the next press's command is not a latency
    rate = report.get("published", 0) / max(report.get("seconds", 1.0), 1e-9)
    print(f"publisher sent {rate:.0f} msg/s (its own CPU {report.get('cpu', 0):.1f} s, not counted)")
    target = 15 if args.agents <= 200 else 30
    print(
        f"console CPU: {share * 100:.1f} % of one core (target < {target} %; load average {os.getloadavg()[0]:.2f})"
    )
    us_per_msg = share * 1e6 / max(rate, 1e-9)
    print(
        f"  per message received: {us_per_msg:.1f} us of console CPU; reference {ref:.2f} us "
        f"(raw lcm, same run): {us_per_msg / ref:.2f} x ref"
    )
    per_thread = {tid: (cpu - threads0.get(tid, 0.0)) / (t1 - t0) for tid, cpu in threads1.items()}
    others = sorted((share for tid, share in per_thread.items() if tid != tui.pid), reverse=True)
    print(
        f"  by thread: UI {per_thread.get(tui.pid, 0.0) * 100:.1f} %, others "
        + ", ".join(f"{x * 100:.1f} %" for x in others if x >= 0.005)
        + " (the bus executor, Textual's writer; with liblcm also its receive thread)"
    )
    print(f"console output: {(out1 - out0) / (t1 - t0) / 1024:.0f} KiB/s to the terminal")
    if lat:
        srt = sorted(lat)
        p99 = srt[min(len(srt) - 1, max(0, math.ceil(0.99 * len(srt)) - 1))]
        print(
            f"key -> command on the wire: median {statistics.median(lat) * 1000:.1f} ms, "
            f"p99 {p99 * 1000:.1f} ms (target < 50 ms), max {max(lat) * 1000:.1f} ms over {len(lat)} key presses"
        )
    else:
        print("key -> command on the wire: no command arrived (keys not delivered?)")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", type=int, default=200)
    parser.add_argument("--hz", type=float, default=5.0, help="rate of each state/telemetry topic per agent")
    parser.add_argument("--seconds", type=float, default=20.0, help="measurement window")
    parser.add_argument("--size", default="160x50", help="terminal COLSxROWS")
    parser.add_argument("--arbiter", action="store_true", help="also publish arbiter_status_t at --hz")
    parser.add_argument(
        "--profile", metavar="PATH", help="run the console under cProfile (UI thread), write stats"
    )
    parser.add_argument(
        "--reader",
        choices=["own", "liblcm"],
        default="own",
        help="who reads udpm:// in the console: its own socket (default) or liblcm's receive thread",
    )
    parser.add_argument(
        "--baseline", action="store_true", help="run twice in this run: own reader, then liblcm's"
    )
    parser.add_argument(
        "--role", choices=["main", "publisher", "reference"], default="main", help=argparse.SUPPRESS
    )
    parser.add_argument("--url", default=URL, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "publisher":
        return run_publisher(args.url, args.agents, args.hz, args.arbiter)
    if args.role == "reference":
        from benchmarks._reference import reference

        print(f"{reference(args.url):.4f}", flush=True)
        return 0

    from tests.harness.netns import netns_unavailable

    reason = netns_unavailable()
    if reason:
        print(f"benchmarks/tui.py needs a private network namespace: {reason}", file=sys.stderr)
        return 2
    cols, rows = (int(x) for x in args.size.split("x"))
    topics = 4 if args.arbiter else 3
    print(
        f"operator console: {args.agents} agents x {topics} topics at {args.hz:g} Hz "
        f"= {args.agents * topics * args.hz:.0f} msg/s, terminal {cols}x{rows}, {args.seconds:g} s window"
    )
    readers = ["own", "liblcm"] if args.baseline else [args.reader]
    for reader in readers:
        print(
            f"-- udpm:// read by {'the console own socket' if reader == 'own' else 'liblcm'} (ANTALATE_UDPM_READER={reader})"
        )
        rc = measure(args, reader)
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
