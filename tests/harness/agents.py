"""The one config builder of the tests and the agent runner across processes.

``agent_config``: an agent's config as a dict (the simulator, brisk, on the namespace's multicast bus);
``swarm_config``: the TOML text of an experiment's agent (``antalate run`` copies it into a swarm: the
simulator at its own speeds, every topic on the one bus, one BMA); ``AgentProcesses``: an agent's
nodes, each its own ``antalate`` process in a namespace. The agents of one process are
``tests.harness.memory_agent``'s; whole swarms across hosts are ``tests.lan.swarm``'s.
"""

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
    name: str = "alpha",
    *,
    sim: dict[str, Any] | None = None,
    bus: str = MCAST_URL,
    fast: bool = True,
    autopilot: str = "sim",
    takeoff: float | None = 3.0,
    **sections: Any,
) -> dict[str, Any]:
    """``sim`` adds to (``fast``) or replaces the simulator's speed-ups (the adapter's params, whatever
    the ``autopilot``); ``takeoff`` None leaves the config's default; ``sections`` are the config's other
    tables (``hlc`` merged into the one built here)."""
    hlc: dict[str, Any] = {"autopilot": autopilot}
    if takeoff is not None:
        hlc["default_takeoff_altitude"] = takeoff
    hlc.update(sections.pop("hlc", {}))
    params = {**(FAST_SIM if fast else {}), **(sim or {})}
    if params:
        hlc["autopilot_params"] = params
    doc: dict[str, Any] = {"agent": {"name": name}, "buses": {"lan": bus}, "hlc": hlc}
    doc.update(sections)
    return doc


def swarm_config(
    name: str,
    *behaviors: dict[str, Any],
    bus: str = "memq://",
    bma: str = "m",
    takeoff: float = 5.0,
    sim: dict[str, Any] | None = None,
    autopilot: str = "sim",
) -> str:
    """The TOML of an experiment's agent: ``behaviors`` (``{"plugin": ..., ...}`` each) in one BMA."""
    doc = agent_config(
        name,
        sim=sim,
        bus=bus,
        fast=False,
        autopilot=autopilot,
        takeoff=takeoff,
        topics={"default_bus": "lan"},
        bma=[{"name": bma, "behaviors": list(behaviors)}],
    )
    return tomli_w.dumps(doc)


class AgentProcesses:
    """The nodes of one agent, each its own ``antalate`` process inside ``netns``."""

    def __init__(self, netns: NetNamespace, tmp_path: Path, doc: dict[str, Any]) -> None:
        self.netns = netns
        self.name: str = doc["agent"]["name"]
        self.doc = doc
        self.path = tmp_path / f"{self.name}.toml"
        self.path.write_text(tomli_w.dumps(doc))
        self.procs: dict[str, subprocess.Popen[str]] = {}
        #: The log of each node's latest run; ``runs``: every run's, in the order started.
        self.logs: dict[str, Path] = {}
        self.runs: list[Path] = []
        self._tmp = tmp_path

    def start(self, node: str, *extra: str) -> subprocess.Popen[str]:
        log = self._tmp / f"{self.name}-{node}-{len(self.runs) + 1}.log"
        self.logs[node] = log
        self.runs.append(log)
        out = open(log, "w")  # noqa: SIM115 - closed with the process
        proc = self.netns.antalate(node, str(self.path), *extra, stdout=out, stderr=subprocess.STDOUT)
        self.procs[node] = proc
        return proc

    def kill(self, node: str) -> None:
        """SIGKILL: the node gets no chance to say goodbye (a crash, as a test means it)."""
        proc = self.procs.pop(node)
        proc.kill()
        proc.wait(10)

    def alive(self, node: str) -> bool:
        return self.procs[node].poll() is None

    def log(self, node: str | None = None) -> str:
        """``node``'s latest log, or every log of this agent in the order the nodes started."""
        if node is not None:
            return self.logs[node].read_text(errors="replace")
        return "".join(p.read_text(errors="replace") for p in self.runs)

    def stop(self) -> dict[str, int | None]:
        return {node: stop_process(proc) for node, proc in self.procs.items()}
