"""Spoofed datagrams on real UDP multicast (a private namespace): an agent whose nodes share a process
never hears them on its internal topics, even with no key; separate processes refuse to run unsigned."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t, mc_state_t, operator_cmd_t, velocity_cmd_t
from tests.conftest import Probe
from tests.harness.agents import AgentProcesses, agent_config
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for

pytestmark = pytest.mark.netns

M, H = mc_state_t, hlc_state_t


def _spoof(probe: Probe, n: int = 10) -> None:
    """The issue's three datagrams, as an attacker on the LAN sends them (unsigned, fresh header)."""
    for _ in range(n):
        header = {"utime": int(time.time() * 1e6), "agent": "alpha", "seq": 1}
        probe.publish("alpha/MC_STATE", "mc_state_t", header=header, state=M.TAKEOFF)
        probe.publish("alpha/HLC_STATE", "hlc_state_t", header=header, state=H.LLC_DOWN)
        probe.publish("alpha/VELOCITY_CMD", "velocity_cmd_t", header=header, frame=velocity_cmd_t.NED, vx=3.2)


def _before(msgs: list[dict[str, Any]], utime: int) -> list[dict[str, Any]]:
    return [m for m in msgs if m["header"]["utime"] < utime]


def test_an_in_process_agent_never_hears_spoofed_internal_topics(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    agent = AgentProcesses(netns, tmp_path, agent_config("alpha"))  # no key at all
    try:
        agent.start("agent")
        assert probe.wait("alpha/HLC_STATE", "hlc_state_t", timeout=20, state=H.READY), agent.log("agent")
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=10, state=M.STANDBY)
        mark = probe.mark()
        _spoof(probe)
        # Sync: an operator command sent after the spoofs (unsigned is fine without a key). Once the MC
        # acknowledges it, the spoofs, delivered earlier on the same socket, have had every chance.
        probe.publish(
            "SWARM/OPERATOR_CMD",
            "operator_cmd_t",
            header={"utime": int(time.time() * 1e6), "agent": "operator", "seq": 78},
            command=operator_cmd_t.TAKEOFF,
            altitude=0.0,
        )
        ack = probe.wait("alpha/MC_STATE", "mc_state_t", timeout=10, since=mark, last_command_seq=78)
        assert ack is not None, agent.log("agent")
        t = ack["header"]["utime"]
        mc = _before(probe.history("alpha/MC_STATE", "mc_state_t", since=mark), t)
        hlc = _before(probe.history("alpha/HLC_STATE", "hlc_state_t", since=mark), t)
        tel = _before(probe.history("alpha/TELEMETRY", "telemetry_t", since=mark), t)
        # our own spoofs are in the history too (multicast loops back): only the agent's own count
        # (an MC in ERROR would have refused the TAKEOFF: the acknowledgement itself says it was not)
        assert {m["state"] for m in mc if m["header"]["seq"] != 1} <= {M.STANDBY}
        assert {m["state"] for m in hlc if m["header"]["seq"] != 1} <= {H.READY}
        assert not any(m["armed"] or abs(m["vn"]) > 0.1 for m in tel)
    finally:
        agent.stop()


def test_the_same_spoof_grounds_separate_insecure_processes(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    """The control for the test above: with each node in its own process and `insecure = true`,
    one spoofed hlc_state_t LLC_DOWN does put the MC in ERROR (what the refusal to start prevents)."""
    agent = AgentProcesses(netns, tmp_path, agent_config("alpha", security={"insecure": True}))
    try:
        agent.start("hlc")
        agent.start("mc")
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=20, state=M.STANDBY), agent.log("mc")
        _spoof(probe, n=1)
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=10, state=M.ERROR)
        assert "INSECURE" in agent.log("mc")
    finally:
        agent.stop()


def test_a_separate_node_without_a_key_refuses_to_start(netns: NetNamespace, tmp_path: Path) -> None:
    agent = AgentProcesses(netns, tmp_path, agent_config("alpha"))
    proc = agent.start("mc")
    assert wait_for(lambda: proc.poll() is not None, 30)
    log = agent.log("mc")
    assert proc.returncode == 2, log
    line = next(ln for ln in log.splitlines() if ln.startswith("antalate: "))
    assert "HLC_STATE" in line and "'lan'" in line and "swarm_key" in line and "insecure = true" in line
    assert "Traceback" not in log


def test_signed_separate_processes_fly_and_ignore_unsigned_spoofs(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    key = "multicast-test-key"
    agent = AgentProcesses(
        netns, tmp_path, agent_config("alpha", security={"swarm_key": key, "state_dir": str(tmp_path)})
    )
    try:
        agent.start("hlc")
        agent.start("mc")
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=20, state=M.STANDBY), agent.log("mc")
        mark = probe.mark()
        _spoof(probe)
        # the MC republishes its state at 5 Hz: a few periods after the spoofs, still STANDBY, and it said why
        assert wait_for(
            lambda: "unsigned message" in agent.log("mc") and "unsigned message" in agent.log("hlc"), 10
        )
        # a genuine state of each since (the spoofs say TAKEOFF and LLC_DOWN): at load the probe's own
        # spoofs, looped back late, once were all it had heard of HLC_STATE here, and the set below was empty
        later = probe.mark()
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=5, since=later, state=M.STANDBY)
        assert probe.wait("alpha/HLC_STATE", "hlc_state_t", timeout=5, since=later, state=H.READY), agent.log(
            "hlc"
        )
        # the genuine messages are the signed ones (the spoofs carry no MAC; a genuine seq may be 1 too)
        states = {
            m["state"]
            for m in probe.history("alpha/MC_STATE", "mc_state_t", since=mark)
            if m["header"]["mac_len"] > 0
        }
        assert states == {M.STANDBY}
        hlc = {
            m["state"]
            for m in probe.history("alpha/HLC_STATE", "hlc_state_t", since=mark)
            if m["header"]["mac_len"] > 0
        }
        assert hlc == {H.READY}
    finally:
        agent.stop()
