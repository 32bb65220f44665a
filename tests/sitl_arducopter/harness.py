"""ArduCopter 4.6.3 SITL in a private network namespace, flown by a whole ``antalate agent`` process.

`Copter` is one vehicle and its agent inside the test's namespace: the ``arducopter`` binary (from
``ANTALATE_ARDUCOPTER_SITL``, default ``../shared/sitl/arducopter/arducopter`` from the project root,
with ``copter.parm`` beside it; ../shared/sitl/README.md), a `gcs` helper that relays the agent's TCP
link to SERIAL0 (so the test can cut or stall it) and watches the vehicle on SERIAL1, and the agent (MC +
HLC with the ``mavlink`` adapter + a BMA running ``direction_follow``, or ``dovrat_swarm``).
`SitlVehicle`, `Gcs` and `agent_doc` are shared with the PX4 SITL tests (tests/sitl_px4/harness.py).

``backend="emulator"`` puts the project's ArduCopter emulator (tests/emulators/mavlink_vehicle.py, its
``arducopter`` profile) where the firmware was, on the same TCP port, behind the same relay and ground
station: the comparison tests fly one scenario table against both.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from tests import REPO
from tests.conftest import MCAST_URL
from tests.harness.agents import AgentProcesses
from tests.harness.jsonl import JsonLinesProcess
from tests.harness.netns import NetNamespace
from tests.harness.process import stop_process

DEFAULT_SITL = REPO / ".." / "shared" / "sitl" / "arducopter" / "arducopter"
HOME = (-35.363261, 149.165230, 584.0, 353.0)
RELAY_PORT = 15760  # + 10 N: where the agent connects


@contextlib.contextmanager
def one_sitl_swarm_at_a_time() -> Iterator[None]:
    """Held by a module that flies three SITL vehicles at once, for as long as they fly.

    Three ArduCopters and three PX4s booted together on two cores (the suite's two workers each in
    such a module) starved the simulators: a PX4 lost its simulated sensors and never took off, and
    an ArduCopter swarm came 1 cm inside its margin. One such module at a time across the workers;
    the other worker's single-vehicle modules and the rest of the suite go on beside it.
    """
    path = Path(tempfile.gettempdir()) / "antalate-sitl-swarm.lock"
    with path.open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def sitl_binary() -> Path:
    return Path(os.environ.get("ANTALATE_ARDUCOPTER_SITL", str(DEFAULT_SITL))).resolve()


def sitl_missing() -> str | None:
    """Why the SITL tests cannot run here (None: they can)."""
    binary = sitl_binary()
    if not binary.is_file() or not os.access(binary, os.X_OK):
        return (
            f"no ArduCopter SITL binary at {binary} (set ANTALATE_ARDUCOPTER_SITL; ../shared/sitl/README.md)"
        )
    if not (binary.parent / "copter.parm").is_file():
        return f"no copter.parm beside {binary}"
    return None


class Gcs(JsonLinesProcess):
    """Client of `gcs`: the vehicle's own record, a second ground station, and the link's relay.

    ``args``: `gcs`'s command line (its link to the vehicle, ``--stack``, the relay).
    """

    def __init__(self, netns: NetNamespace, *args: str) -> None:
        proc = netns.python(
            "-m",
            "tests.sitl_arducopter.gcs",
            *args,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        super().__init__(proc, "the SITL ground station")

    def ok(self, **req: Any) -> dict[str, Any]:
        reply = self.call(**req)
        assert reply["ok"], reply
        return reply

    def state(self, system: int | None = None) -> dict[str, Any]:
        return self.ok(op="state") if system is None else self.ok(op="state", system=system)

    def set_param(self, name: str, value: float, *, integer: bool = False) -> None:
        self.ok(op="set_param", name=name, value=value, int=integer)

    def relay(self, mode: str) -> None:
        self.ok(op="relay", mode=mode)

    def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG from the second ground station, ACCEPTED (MAV_CMD_BATTERY_RESET, ...)."""
        self.ok(op="command", command=command, params=list(params))


def agent_doc(
    name: str,
    adapter: str,
    connection: str,
    *,
    bma: list[dict[str, Any]] | None = None,
    hlc: dict[str, Any] | None = None,
    autopilot: dict[str, Any] | None = None,
    sections: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The agent's config for a SITL vehicle: MC + HLC (`adapter` on `connection`) + a BMA flying
    ``direction_follow`` in MISSION unless `bma` says otherwise; `sections` adds more ([safety], ...)."""
    return {
        "agent": {"name": name},
        "buses": {"lan": MCAST_URL},
        "hlc": {
            "autopilot": adapter,
            "default_takeoff_altitude": 5.0,
            "gain_altitude_timeout": 40.0,
            **(hlc or {}),
            "autopilot_params": {
                "connection": connection,
                "ready_timeout": 120.0,
                "stream_rate_hz": 10.0,
                **(autopilot or {}),
            },
        },
        "bma": bma
        or [
            {
                "name": "pilot",
                "behaviors": [{"plugin": "direction_follow", "activate_on": ["MISSION"]}],
            }
        ],
        "security": {"insecure": True},  # the probe plays an unsigned operator
        **(sections or {}),
    }


class SitlVehicle:
    """A SITL firmware process, the `Gcs` beside it and the agent that flies it (subclasses start them)."""

    netns: NetNamespace
    name: str
    gcs: Gcs
    sitl: subprocess.Popen[str]
    agent: AgentProcesses
    nodes: tuple[str, ...]
    booted_at: float
    workdir: Path

    def start(self, node: str) -> None:
        """Start ``node`` ("agent", or "hlc", "mc", "bma" each in its own process)."""
        if node == "bma":
            self.agent.start("bma", "--name", "pilot")
        else:
            self.agent.start(node)

    def start_agent(self, workdir: Path, doc: dict[str, Any], nodes: tuple[str, ...]) -> None:
        self.agent = AgentProcesses(self.netns, workdir, doc)
        self.nodes = nodes
        for node in nodes:
            self.start(node)

    def stop(self) -> None:
        self.agent.stop()
        stop_process(self.sitl)
        stop_process(self.gcs.proc)

    def tails(self, lines: int = 25) -> str:
        """The last `lines` of each of this vehicle's logs (the agent's nodes, the firmware's own)."""
        out = []
        for path in sorted(self.workdir.glob("*.log")):  # the agent's nodes write theirs here too
            text = path.read_text(errors="replace").splitlines()
            out.append(f"--- {self.name}: {path.name}, last {lines} lines ---\n" + "\n".join(text[-lines:]))
        return "\n".join(out)

    @contextlib.contextmanager
    def explained(self) -> Iterator[None]:
        """An assertion failing inside says what this vehicle's logs ended with: CI keeps no files, and
        a failure without them cannot be told apart (refused arming, a failsafe, a starved simulator)."""
        try:
            yield
        except AssertionError as e:
            raise AssertionError(f"{e}\n{self.tails()}") from None


class Copter(SitlVehicle):
    """SITL instance ``instance`` (system id instance + 1) and the agent ``name`` that flies it."""

    def __init__(
        self,
        netns: NetNamespace,
        workdir: Path,
        *,
        instance: int = 0,
        name: str = "copter",
        bma: list[dict[str, Any]] | None = None,
        speedup: float = 1.0,
        home: tuple[float, float, float, float] = HOME,
        hlc: dict[str, Any] | None = None,
        autopilot: dict[str, Any] | None = None,
        nodes: tuple[str, ...] = ("agent",),
        sections: dict[str, Any] | None = None,
        backend: str = "arducopter",
    ) -> None:
        self.netns, self.instance, self.name, self.backend = netns, instance, name, backend
        workdir.mkdir(parents=True, exist_ok=True)
        self.workdir = workdir
        serial0 = 5760 + 10 * instance
        # the relay listens before the agent connects; the emulator takes any number of TCP clients, so
        # its "SERIAL1" is SERIAL0's port
        self.gcs = Gcs(
            netns,
            f"tcp:127.0.0.1:{serial0 if backend == 'emulator' else serial0 + 2}",
            "--tcp-relay",
            f"{RELAY_PORT + 10 * instance}:{serial0}",
        )
        self.booted_at = time.monotonic()
        self.sitl = self._emulator(home) if backend == "emulator" else self._sitl(workdir, speedup, home)
        connection = f"tcp:127.0.0.1:{RELAY_PORT + 10 * instance}"
        doc = agent_doc(name, "mavlink", connection, bma=bma, hlc=hlc, autopilot=autopilot, sections=sections)
        self.start_agent(workdir, doc, nodes)
        self.gcs.ok(op="connect")

    def _emulator(self, home: tuple[float, float, float, float]) -> subprocess.Popen[str]:
        return self.netns.popen(
            [
                sys.executable,
                "-m",
                "tests.emulators.mavlink_vehicle",
                "--profile",
                "arducopter",
                "--udp-port",
                "-1",
                "--tcp-port",
                str(5760 + 10 * self.instance),
                "--sysid",
                str(self.instance + 1),
                "--home=" + ",".join(f"{x:.10g}" for x in home[:3]),  # "=": the latitude starts with "-"
                "--log-level",
                "INFO",
            ],
            cwd=str(REPO),
            stdout=open(self.workdir / "emulator.log", "w"),  # noqa: SIM115 - closed with the process
            stderr=subprocess.STDOUT,
        )

    def _sitl(
        self, workdir: Path, speedup: float, home: tuple[float, float, float, float]
    ) -> subprocess.Popen[str]:
        binary = sitl_binary()
        return self.netns.popen(
            [
                str(binary),
                "--model",
                "+",
                "--speedup",
                f"{speedup:g}",
                "--home",
                ",".join(f"{x:.10g}" for x in home),  # ":g" kept 6 digits: 21 m off in longitude
                "--defaults",
                str(binary.parent / "copter.parm"),
                "--instance",
                str(self.instance),
                "-w",
                "--sysid",
                str(self.instance + 1),
            ],
            cwd=str(workdir),
            stdout=open(workdir / "sitl.log", "w"),  # noqa: SIM115 - closed with the process
            stderr=subprocess.STDOUT,
        )
