"""Five vehicle computers and an operator laptop on a simulated LAN, running the example configs.

:class:`LanSwarm` builds the :class:`~tests.lan.topology.Lan`, writes each vehicle's config from
``examples/lan/uav-N.toml`` (only made fast for a test: quick simulated climbs and landings, a low
altitude, a slow forward speed so the direction command dominates the motion), and starts

* on the operator host: the reference station (the OSCs report to it over the LAN), ``lcm-logger``
  on the LAN bus (what the operator heard, for ``antalate analyze``) and the operator console
  (:mod:`tests.lan.lan_operator`);
* on each vehicle host: ``antalate agent`` with its config, or for the hosts in ``split`` each node
  as its own process (``antalate hlc|mc|bma|osc``: they meet on the host's local bus), and for the
  hosts in ``local_log`` an ``lcm-logger`` on the host's local bus (what the agent's own nodes said).
"""

from __future__ import annotations

import copy
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import tomli_w

from antalate_lcm.runtime.cli import native_lcm_tool
from tests import REPO
from tests.harness.agents import FAST_SIM
from tests.harness.jsonl import JsonLinesProcess
from tests.harness.lifecycle import Started
from tests.harness.process import stop_process
from tests.lan.topology import Lan

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

EXAMPLES = REPO / "examples" / "lan"
VEHICLES = tuple(f"uav-{i}" for i in range(1, 6))
OPERATOR = "operator"
LAN_URL = "udpm://239.255.76.67:7667?ttl=1"
LOCAL_URL = "udpm://239.255.76.68:7668?ttl=0"
STATION_PORT = 8080
ALTITUDE = 3.0
#: The swarm key of the test LAN (every vehicle and the operator): split hosts run each node in its
#: own process on multicast, which needs one (docs/security.md).
SWARM_KEY = "lan-test-swarm-key"


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for key, value in extra.items():
        out[key] = (
            _merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
        )
    return out


def vehicle_config(name: str, out_dir: Path, forward_speed: float = 0.3) -> Path:
    """The example config of ``name``, with only the test's speed-ups, written to ``out_dir``."""
    doc = tomllib.loads((EXAMPLES / f"{name}.toml").read_text())
    doc = _merge(
        doc,
        {
            "hlc": {"default_takeoff_altitude": ALTITUDE, "autopilot_params": FAST_SIM},
            "security": {"swarm_key": SWARM_KEY, "state_dir": str(out_dir / f"{name}-state")},
        },
    )
    for bma in doc.get("bma", []):
        for behavior in bma.get("behaviors", []):
            if behavior["plugin"] == "dovrat_swarm":
                behavior["params"] = {**behavior.get("params", {}), "forward_speed": forward_speed}
    path = out_dir / f"{name}.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


class OperatorClient(JsonLinesProcess):
    """Talks to :mod:`tests.lan.lan_operator` running in the operator host."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        super().__init__(proc, "the operator console")

    def status(self) -> dict[str, Any]:
        return self.call(op="status")

    def command(self, command: str, target: str = "", altitude: float = 0.0) -> int:
        return int(self.call(op="command", command=command, target=target, altitude=altitude)["seq"])

    def direction(self, azimuth: float, speed: float, active: bool = True) -> None:
        self.call(op="direction", azimuth=azimuth, speed=speed, active=active)

    def wait(self, predicate: Callable[[dict[str, Any]], bool], timeout: float, what: str) -> dict[str, Any]:
        """Poll the status until ``predicate`` holds; fail with the last status otherwise."""
        deadline = time.monotonic() + timeout
        while True:
            status = self.status()
            if predicate(status):
                return status
            if time.monotonic() > deadline:
                agents = {a: (v["mc"], round(v["mc_age"] or -1, 1)) for a, v in status["agents"].items()}
                raise AssertionError(
                    f"timed out after {timeout:g} s waiting for {what}; agents: {agents}; "
                    f"commands: {status['commands']}"
                )
            time.sleep(0.2)

    def wait_all(self, agents: Iterable[str], state: str, timeout: float) -> dict[str, Any]:
        names = list(agents)
        return self.wait(
            lambda s: all(s["agents"].get(a, {}).get("mc") == state for a in names),
            timeout,
            f"{', '.join(names)} in {state}",
        )

    def quit(self) -> None:
        if self.proc.poll() is None:
            try:
                self.call(op="quit")
                self.proc.wait(5)
            except (OSError, RuntimeError, subprocess.TimeoutExpired, ValueError):
                pass
        stop_process(self.proc)


class LanSwarm(Started):
    """The whole set-up for one test; a context manager that tears everything down."""

    def __init__(
        self,
        tmp_path: Path,
        *,
        vehicles: Iterable[str] = VEHICLES,
        loss: int = 0,
        split: Iterable[str] = (),
        local_log: Iterable[str] = (),
    ) -> None:
        self.tmp = tmp_path
        self.vehicles = list(vehicles)
        self.loss = loss
        self.split = set(split)
        self.local_log = set(local_log)
        self.lan = Lan([*self.vehicles, OPERATOR])
        self.op: OperatorClient | None = None
        self.lan_log = tmp_path / "operator-lan.lcm"
        self.logs: dict[str, Path] = {}

    def local_log_path(self, name: str) -> Path:
        return self.tmp / f"{name}-local.lcm"

    def __enter__(self) -> LanSwarm:
        self.lan.__enter__()
        return super().__enter__()

    def close(self) -> None:
        if self.op is not None:
            self.op.quit()
        self.lan.close()

    def _log(self, label: str) -> Path:
        path = self.tmp / f"{label}.log"
        self.logs[label] = path
        return path

    def _start(self) -> None:
        operator = self.lan[OPERATOR]
        station = f"http://{operator.address}:{STATION_PORT}"
        configs = {name: vehicle_config(name, self.tmp) for name in self.vehicles}
        for name in self.vehicles:
            text = configs[name].read_text()
            assert station in text, f"examples/lan/{name}.toml must report to the operator host {station}"
        if self.loss:
            self.lan.set_loss(self.loss)
        logger = native_lcm_tool("lcm-logger")
        operator.antalate(
            "--log-level",
            "WARNING",
            "station",
            "--host",
            operator.address,
            "--port",
            str(STATION_PORT),
            "--db",
            ":memory:",
            "--range",
            "30",
            "--fov",
            "90",
            log=self._log("station"),
        )
        operator.popen(
            [logger, "--quiet", "--force", f"--lcm-url={LAN_URL}", str(self.lan_log)],
            log=self._log("operator-logger"),
        )
        for name in self.vehicles:
            host, cfg = self.lan[name], str(configs[name])
            if name in self.local_log:
                host.popen(
                    [logger, "--quiet", "--force", f"--lcm-url={LOCAL_URL}", str(self.local_log_path(name))],
                    log=self._log(f"{name}-logger"),
                )
            if name in self.split:
                host.antalate("hlc", cfg, log=self._log(f"{name}-hlc"))
                host.antalate("mc", cfg, log=self._log(f"{name}-mc"))
                host.antalate("bma", cfg, "--name", "swarm", log=self._log(f"{name}-bma"))
                host.antalate("osc", cfg, log=self._log(f"{name}-osc"))
            else:
                host.antalate("agent", cfg, log=self._log(f"{name}-agent"))
        op_cfg = self.tmp / "operator.toml"
        op_doc = _merge(
            tomllib.loads((EXAMPLES / "operator.toml").read_text()), {"security": {"swarm_key": SWARM_KEY}}
        )
        op_cfg.write_text(tomli_w.dumps(op_doc))
        proc = operator.popen(
            [sys.executable, "-m", "tests.lan.lan_operator", str(op_cfg), "--stale-after", "2"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        self.op = OperatorClient(proc)

    def log_text(self, label: str) -> str:
        return self.logs[label].read_text() if label in self.logs and self.logs[label].exists() else ""

    def stop_loggers(self) -> None:
        """Stop every lcm-logger (they flush and close their files) before the logs are read."""
        for host in self.lan.hosts.values():
            for proc in list(host.procs):
                if isinstance(proc.args, list) and any("lcm-logger" in str(a) for a in proc.args):
                    stop_process(proc)
