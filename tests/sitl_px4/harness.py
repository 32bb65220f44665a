"""PX4 v1.15.4 SITL (SIH) in a private network namespace, flown by a whole ``antalate`` agent.

`Px4` is one vehicle and its agent inside the test's namespace: PX4 started by the launcher of
``ANTALATE_PX4_SITL`` (default ``../shared/sitl/px4`` from the project root; ../shared/sitl/README.md),
the agent (MC + HLC with the ``px4`` adapter + a BMA) and the ArduCopter tests' `Gcs` helper in its PX4
form: PX4's own record of the flight on its GCS link (udp 14550) and, between the adapter and PX4's
offboard link, a UDP relay the test can cut or stall. The launcher wipes PX4's stored parameters at
each start; ``PX4_PARAMS`` sets the test's (logging off, shorter RTL and landing).
"""

from __future__ import annotations

import functools
import os
import subprocess
import time
from pathlib import Path
from typing import Any

from tests import REPO
from tests.harness.netns import NetNamespace
from tests.harness.process import child_env, stop_process
from tests.sitl_arducopter.harness import Gcs, SitlVehicle, agent_doc

DEFAULT_SITL = REPO / ".." / "shared" / "sitl" / "px4"
#: Where PX4 SITL instance N sends its offboard link (../shared/sitl/px4/README.txt); the relay takes it.
OFFBOARD_PORT = 14540
#: + N: where the adapter listens (udpin) behind the relay.
ADAPTER_PORT = 24540
#: PX4's GCS link sends here (all instances), the `Gcs` helper listens.
GCS_URL = "udpin:127.0.0.1:14550"
#: SIH's default start (run-px4-sih.sh).
SIH_HOME = (45.4671160, -73.7578370)
#: Logging off (16 MB a run), RTL home at 8 m instead of 60 m, a quicker final descent: shorter flights.
TEST_PARAMS = {"SDLOG_MODE": -1, "RTL_RETURN_ALT": 8, "RTL_DESCEND_ALT": 5, "MPC_LAND_SPEED": 1.2}


def sitl_dir() -> Path:
    return Path(os.environ.get("ANTALATE_PX4_SITL", str(DEFAULT_SITL))).resolve()


def sitl_missing() -> str | None:
    """Why the PX4 SITL tests cannot run here (None: they can)."""
    root = sitl_dir()
    launcher = root / "run-px4-sih.sh"
    if not launcher.is_file() or not os.access(root / "bin" / "px4", os.X_OK):
        return f"no PX4 SITL (run-px4-sih.sh, bin/px4) in {root} (set ANTALATE_PX4_SITL; ../shared/sitl/README.md)"
    return None


def link_commands(workdir: Path) -> None:
    """Make PX4's shell commands (``px4-param``, ``px4-commander`` ...) runnable from `workdir`.

    The build installs them as symlinks to ``bin/px4`` (PX4 runs as the command its name says); a copy
    of the directory that lost its symlinks (an archive or artifact store that keeps files only) has
    3-byte text files instead, and PX4's startup script fails ("px4-param: Permission denied"). The
    launcher puts ``WORKDIR/.rc`` first on PATH (its parameter overrides live there): symlinks there
    make such a copy work, and change nothing for an intact one.
    """
    bin_dir = sitl_dir() / "bin"
    rc = workdir / ".rc"
    rc.mkdir(parents=True, exist_ok=True)
    for command in bin_dir.glob("px4-*"):
        if command.suffix or os.access(command, os.X_OK):
            continue
        link = rc / command.name
        if not link.is_symlink():
            link.symlink_to(bin_dir / "px4")


@functools.cache
def ahead_of_the_suite() -> tuple[str, ...]:
    """The host-side prefix that runs PX4 ahead of the suite's other processes, as a real PX4 has a
    processor of its own.

    PX4 asks for SCHED_FIFO for its threads, but inside the test's user namespace it may not, and
    falls back to the policy it was started with. Under the usual policy, even at nice -10, PX4s
    starved by a loaded machine (load 7 on 2 cores: four workers, SITL vehicles, the suite) lost
    their simulated sensors just after arming ("Accel #0 fail: TIMEOUT", "No valid data from
    Baro 0", "Failsafe: blind land"), in CI and here. A real-time round-robin policy (set from the
    host, which the namespace's own root cannot) puts PX4's threads ahead of every ordinary process;
    each PX4 uses about a tenth of a core, and the kernel keeps 5 % of each second for the rest
    (sched_rt_runtime_us). Where the host refuses real time (no CAP_SYS_NICE), nice -10, or the
    usual priority where nice is refused too (nice then says so in px4.log).
    """
    try:
        rt = subprocess.run(["chrt", "--rr", "10", "true"], capture_output=True, check=False).returncode == 0
    except FileNotFoundError:  # no util-linux
        rt = False
    return ("chrt", "--rr", "10") if rt else ("nice", "-n", "-10")


def px4_gcs(netns: NetNamespace, *relay: str) -> Gcs:
    """The `Gcs` helper on PX4's GCS link, with ``--udp-relay LISTEN:ADAPTER`` when `relay` says so."""
    return Gcs(netns, GCS_URL, "--stack", "px4", *relay)


class Px4(SitlVehicle):
    """PX4 SITL instance ``instance`` (system id instance + 1) and the agent ``name`` that flies it.

    ``gcs``: a `Gcs` shared by several vehicles (a swarm: no relay, the adapter on PX4's offboard port
    directly); by default each vehicle has its own, with the relay. ``home``: SIH's start (lat, lon),
    default the launcher's.
    """

    def __init__(
        self,
        netns: NetNamespace,
        workdir: Path,
        *,
        instance: int = 0,
        name: str = "copter",
        bma: list[dict[str, Any]] | None = None,
        hlc: dict[str, Any] | None = None,
        autopilot: dict[str, Any] | None = None,
        params: dict[str, float] | None = None,
        nodes: tuple[str, ...] = ("agent",),
        gcs: Gcs | None = None,
        home: tuple[float, float] | None = None,
    ) -> None:
        self.netns, self.instance, self.name = netns, instance, name
        self.system = instance + 1
        workdir.mkdir(parents=True, exist_ok=True)
        self.workdir = workdir
        self._own_gcs = gcs is None
        if gcs is None:
            port = ADAPTER_PORT + instance
            self.gcs = px4_gcs(netns, "--udp-relay", f"{OFFBOARD_PORT + instance}:{port}")
        else:
            self.gcs, port = gcs, OFFBOARD_PORT + instance
        env = child_env()
        if home is not None:
            env["SIH_HOME_LAT"], env["SIH_HOME_LON"] = (f"{x:.7f}" for x in home)
        env["PX4_PARAMS"] = " ".join(f"{k}={v:g}" for k, v in {**TEST_PARAMS, **(params or {})}.items())
        self._env = env
        self.flown = False  # PX4 has flown since its boot (SIH must restart to arm again: `halt`)
        self.boot()
        connection = f"udpin:127.0.0.1:{port}"
        autopilot = {"configure_vehicle": True, **(autopilot or {})}
        doc = agent_doc(name, "px4", connection, bma=bma, hlc=hlc, autopilot=autopilot)
        self.start_agent(workdir, doc, nodes)
        self.gcs.ok(op="connect")

    def boot(self) -> None:
        """Start PX4: the first time with the airframe's parameters and the test's, later with what PX4
        stored (the adapter's writes kept, as on a real vehicle: the launcher's PX4_KEEP_PARAMS)."""
        link_commands(self.workdir / "px4")
        self.booted_at = time.monotonic()
        self.flown = False
        self.sitl = self.netns.popen(
            ["sh", str(sitl_dir() / "run-px4-sih.sh"), str(self.instance), str(self.workdir / "px4")],
            outside=ahead_of_the_suite(),
            env=self._env,
            stdin=subprocess.DEVNULL,
            stdout=open(self.workdir / "px4.log", "a"),  # noqa: SIM115 - closed with the process
            stderr=subprocess.STDOUT,
        )

    def halt(self) -> None:
        """Stop PX4, the agent left running (it reconnects when PX4 is `boot`ed again).

        PX4 1.15.4 SIH does not arm again after a landing: its EKF2 pre-arm checks keep failing
        ("Preflight Fail: Yaw estimate error", with COM_ARM_EKF_YAW raised "horizontal velocity
        unstable", > 2 min, the same without antalate: ../shared/sitl/px4/fly_sih.py twice), so a test
        that needs a second flight restarts PX4 (~40 s to ready).
        """
        stop_process(self.sitl)
        self._env["PX4_KEEP_PARAMS"] = "1"

    def state(self) -> dict[str, Any]:
        """PX4's own picture of this vehicle (its GCS link)."""
        return self.gcs.state(self.system)

    def stop(self) -> None:
        self.agent.stop()
        stop_process(self.sitl)
        if self._own_gcs:
            stop_process(self.gcs.proc)
