"""Start an agent's MC and HLC as separate processes in a namespace, from a config written per test."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

from tests.conftest import MCAST_URL
from tests.netns import NetNamespace, stop_process

FAST_SIM = {
    "climb_rate": 5.0,
    "descent_rate": 4.0,
    "rtl_speed": 8.0,
    "land_disarm_delay": 0.2,
}


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def to_toml(doc: dict[str, Any]) -> str:
    """A tiny TOML writer for test configs (tables, arrays of tables, scalars, lists)."""
    lines: list[str] = []

    def table(prefix: str, d: dict[str, Any], array: bool = False) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict) and not _is_table_list(v)}
        lines.append(f"[[{prefix}]]" if array else f"[{prefix}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in scalars.items())
        for k, v in d.items():
            if isinstance(v, dict):
                table(f"{prefix}.{k}", v)
            elif _is_table_list(v):
                for item in v:
                    table(f"{prefix}.{k}", item, array=True)

    for key, value in doc.items():
        if _is_table_list(value):
            for item in value:
                table(key, item, array=True)
        else:
            table(key, value)
    return "\n".join(lines) + "\n"


def _is_table_list(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


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
        self.path.write_text(to_toml(doc))
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
