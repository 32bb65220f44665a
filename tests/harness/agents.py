"""An agent's config for a test (``agent_config``: the simulator, brisk, on the namespace's multicast
bus) and its MC and HLC started as separate processes in a namespace (``AgentProcesses``)."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import tomli_w

from tests.harness.netns import MCAST_URL, NetNamespace
from tests.harness.process import stop_process

FAST_SIM = {
    "climb_rate": 5.0,
    "descent_rate": 4.0,
    "rtl_speed": 8.0,
    "land_disarm_delay": 0.2,
}


def agent_config(
    name: str = "alpha", *, sim: dict[str, Any] | None = None, **sections: Any
) -> dict[str, Any]:
    hlc = {"autopilot": "sim", "default_takeoff_altitude": 3.0, **sections.pop("hlc", {})}
    hlc["autopilot_params"] = {**FAST_SIM, **(sim or {})}
    doc: dict[str, Any] = {"agent": {"name": name}, "buses": {"lan": MCAST_URL}, "hlc": hlc}
    doc.update(sections)
    return doc


class AgentProcesses:
    """The nodes of one agent, each its own ``antalate`` process inside ``netns``."""

    def __init__(self, netns: NetNamespace, tmp_path: Path, doc: dict[str, Any]) -> None:
        self.netns = netns
        self.name = doc["agent"]["name"]
        self.path = tmp_path / f"{self.name}.toml"
        self.path.write_text(tomli_w.dumps(doc))
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self.logs: dict[str, Path] = {}
        self._tmp = tmp_path
        self._runs = 0

    def start(self, node: str, *extra: str) -> subprocess.Popen[str]:
        self._runs += 1
        log = self._tmp / f"{self.name}-{node}-{self._runs}.log"
        self.logs[node] = log
        out = open(log, "w")  # noqa: SIM115 - closed with the process
        proc = self.netns.antalate(node, str(self.path), *extra, stdout=out, stderr=subprocess.STDOUT)
        self.procs[node] = proc
        return proc

    def kill(self, node: str) -> None:
        proc = self.procs.pop(node)
        proc.kill()
        proc.wait(5)

    def alive(self, node: str) -> bool:
        return self.procs[node].poll() is None

    def log(self, node: str) -> str:
        return self.logs[node].read_text()

    def stop(self) -> dict[str, int | None]:
        return {node: stop_process(proc) for node, proc in self.procs.items()}
