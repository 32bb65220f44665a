"""``antalate agent --agents N --processes P``: the agents spread over P processes on the same channels,
and one Ctrl-C (or SIGTERM to the launcher) stops every one of them cleanly."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.config import parse_config
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from antalate_lcm.runtime.agent import (
    AUTO_PROCESSES_FROM,
    default_processes,
    parse_shard,
    shard,
    swarm_configs,
)
from tests.conftest import MCAST_URL, Probe
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for


def test_shards_cover_every_agent_once_in_order() -> None:
    base = parse_config({"agent": {"name": "s"}, "buses": {"lan": "memq://"}, "hlc": {"autopilot": "sim"}})
    configs = swarm_configs(base, 7)
    shares = [shard(configs, i, 3) for i in range(3)]
    assert [c.agent.name for share in shares for c in share] == [c.agent.name for c in configs]
    assert sorted(len(s) for s in shares) == [2, 2, 3]
    assert shard(configs, 0, 1) == configs


def test_shard_option_is_checked() -> None:
    assert parse_shard("1/2") == (1, 2)
    for bad in ("2/2", "-1/2", "x", "1/2/3", ""):
        with pytest.raises(AntalateError, match="--shard"):
            parse_shard(bad)


def test_default_is_one_process_per_core_only_for_a_big_swarm() -> None:
    assert default_processes(AUTO_PROCESSES_FROM - 1) == 1
    assert default_processes(AUTO_PROCESSES_FROM) == max(1, os.cpu_count() or 1)


def _agent_processes(marker: str) -> list[int]:
    """Pids of the processes whose command line names this test's config (ours only)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if marker.encode() in cmdline and b"antalate_lcm.cli" in cmdline:
                out.append(int(entry.name))
    return out


@pytest.mark.netns
@pytest.mark.parametrize("how", ["ctrl-c", "sigterm", "launcher-killed"])
def test_agents_over_two_processes_share_the_channels_and_stop_together(
    netns: NetNamespace, probe: Probe, tmp_path: Path, how: str
) -> None:
    cfg = tmp_path / f"swarm-{how}.toml"
    cfg.write_text(f'[agent]\nname = "p"\n[buses]\nlan = "{MCAST_URL}"\n[hlc]\nautopilot = "sim"\n')
    proc = netns.antalate(
        "--log-level",
        "INFO",
        "agent",
        str(cfg),
        "--agents",
        "4",
        "--processes",
        "2",
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    agents = [f"p-{i:02d}" for i in range(1, 5)]
    for agent in agents:
        assert probe.wait(f"{agent}/MC_STATE", "mc_state_t", timeout=30, state=M.STANDBY), (
            f"{agent} not in STANDBY"
        )
    shards = [
        pid for pid in _agent_processes(str(cfg)) if b"--shard" in Path(f"/proc/{pid}/cmdline").read_bytes()
    ]
    assert len(shards) == 2, "two agent processes, each with its share"
    # one broadcast reaches the agents of both processes: the same channels as one process
    probe.publish("SWARM/OPERATOR_CMD", "operator_cmd_t", header={"seq": 1, "agent": "op"}, command=O.TAKEOFF)
    for agent in agents:
        assert probe.wait(f"{agent}/MC_STATE", "mc_state_t", timeout=20, state=M.MISSION), (
            f"{agent} did not take off"
        )
    if how == "ctrl-c":
        os.killpg(proc.pid, signal.SIGINT)  # the terminal sends SIGINT to the whole foreground group
    elif how == "sigterm":
        proc.send_signal(signal.SIGTERM)  # the launcher alone (a service manager): it stops its children
    else:
        proc.kill()  # SIGKILL: no chance to pass anything on; the children must not fly on alone
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == (-signal.SIGKILL if how == "launcher-killed" else 0), out
    assert wait_for(lambda: not _agent_processes(str(cfg)), 10), "an agent process outlived the launcher"
    assert "Traceback" not in out
