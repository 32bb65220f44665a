"""A fully autonomous agent (the paper's Figure 4): MC + HLC + a BMA running auto_operator, no operator,
each node its own process, over real multicast in a private namespace."""

from __future__ import annotations

from pathlib import Path

import pytest

from antalate_lcm.msgs import mc_state_t as M
from tests.conftest import Probe
from tests.harness.agents import AgentProcesses, agent_config
from tests.harness.netns import NetNamespace

pytestmark = pytest.mark.netns

AUTONOMOUS_BMA = [
    {
        "name": "operator",
        "behaviors": [
            {
                "plugin": "auto_operator",
                "activate_on": ["STANDBY", "MISSION"],
                "params": {"rtl_after": 2.0, "max_flights": 1, "altitude": 3.0},
            }
        ],
    }
]


@pytest.mark.parametrize("layout", ["separate", "one_process"])
def test_autonomous_agent_flies_a_whole_mission(
    netns: NetNamespace, probe: Probe, tmp_path: Path, layout: str
) -> None:
    # Signed: nodes in separate processes on multicast must authenticate each other (docs/security.md).
    doc = agent_config(
        "auto", bma=AUTONOMOUS_BMA, security={"swarm_key": "e2e-autonomous-key", "state_dir": str(tmp_path)}
    )
    agent = AgentProcesses(netns, tmp_path, doc)
    try:
        if layout == "separate":
            agent.start("hlc")
            agent.start("mc")
            agent.start("bma", "--name", "operator")
        else:
            agent.start("agent")
        for state in (M.STANDBY, M.TAKEOFF, M.MISSION, M.RTL):
            assert probe.wait("auto/MC_STATE", "mc_state_t", timeout=20, state=state), (
                f"never reached {state}"
            )
        mark = probe.mark()
        assert probe.wait("auto/MC_STATE", "mc_state_t", timeout=20, since=mark, state=M.STANDBY)
        status = probe.wait("auto/ARBITER/operator", "arbiter_status_t", timeout=5, since=mark)
        assert status is not None and status["arbiter"] == "operator"
        # max_flights = 1: it stays on the ground afterwards
        mark = probe.mark()
        import time

        time.sleep(3.0)
        states = {m["state"] for m in probe.history("auto/MC_STATE", "mc_state_t", since=mark)}
        assert states == {M.STANDBY}
    finally:
        codes = agent.stop()
    assert all(c in (0, -15) for c in codes.values()), codes
