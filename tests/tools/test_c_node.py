"""A node in C flies a Python agent: ``tests/c/takeoff_node.c``, built here from the C types of
``antalate types --lang c`` and liblcm (Debian's liblcm-dev when installed, else the one in the lcm
wheel), reads ``mc_state_t`` from the Python MC and sends ``operator_cmd_t`` TAKEOFF over real
multicast in a private namespace; with a swarm key it signs in C (OpenSSL HMAC-SHA256), and a
wrong key or no signature is refused by the agent."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import time
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from tests import REPO
from tests.conftest import MCAST_URL, Probe
from tests.harness.agents import AgentProcesses, agent_config
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for

pytestmark = pytest.mark.netns

C_SOURCE = REPO / "tests" / "c" / "takeoff_node.c"
KEY = "c-node-test-swarm-key"


def lcm_flags() -> tuple[str, list[str]]:
    """Which liblcm to build against, and the compiler flags for it."""
    if shutil.which("pkg-config") and subprocess.run(["pkg-config", "--exists", "lcm"]).returncode == 0:
        flags = subprocess.run(
            ["pkg-config", "--cflags", "--libs", "lcm"], capture_output=True, text=True, check=True
        )
        return "system liblcm (pkg-config lcm)", flags.stdout.split()
    if Path("/usr/include/lcm/lcm.h").exists():
        return "system liblcm", ["-llcm"]
    site = Path(sysconfig.get_path("platlib"))
    if (site / "include" / "lcm" / "lcm.h").exists() and (site / "lib" / "liblcm.so").exists():
        lib = site / "lib"
        return "the lcm wheel's liblcm", [f"-I{site / 'include'}", f"-L{lib}", f"-Wl,-rpath,{lib}", "-llcm"]
    return "", []


@pytest.fixture(scope="module")
def c_node(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (Debian/Ubuntu: apt-get install gcc)")
    which, flags = lcm_flags()
    if not flags:
        pytest.skip("no liblcm to build against (Debian/Ubuntu: apt-get install liblcm-dev)")
    if not Path("/usr/include/openssl/hmac.h").exists():
        pytest.skip("no OpenSSL headers for the HMAC (Debian/Ubuntu: apt-get install libssl-dev)")
    work = tmp_path_factory.mktemp("c-node")
    types = work / "types"
    gen = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "types", "--lang", "c", "--out", str(types)],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    assert gen.returncode == 0, gen.stderr
    binary = work / "takeoff_node"
    build = subprocess.run(
        [
            cc,
            "-std=c99",
            "-D_DEFAULT_SOURCE",
            "-Wall",
            "-o",
            str(binary),
            str(C_SOURCE),
            *map(str, sorted(types.glob("*.c"))),
            f"-I{types}",
            *flags,
            "-lcrypto",
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert build.returncode == 0, f"building the C node against {which} failed:\n{build.stderr}"
    print(f"C node built against {which}")
    return binary


def run_c_node(
    netns: NetNamespace, binary: Path, key: str | None, ack_timeout: float = 30
) -> tuple[int, list[dict[str, Any]], str]:
    env = {k: v for k, v in os.environ.items() if k != "ANTALATE_SWARM_KEY"}
    if key is not None:
        env["ANTALATE_SWARM_KEY"] = key
    proc = netns.run(
        [str(binary), MCAST_URL, "alpha", "4.0", str(ack_timeout)], timeout=ack_timeout + 70, env=env
    )
    events = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    return proc.returncode, events, proc.stderr


def assert_flew(
    code: int, events: list[dict[str, Any]], stderr: str, probe: Probe, agent: AgentProcesses, mac_len: int
) -> None:
    assert code == 0, f"C node: {events}\n{stderr}\nMC log:\n{agent.log('mc')}"
    states = [e for e in events if e["event"] == "mc_state"]
    first_send = next(i for i, e in enumerate(events) if e["event"] == "sent")
    assert events[first_send - 1]["event"] == "mc_state" and events[first_send - 1]["state"] == M.STANDBY, (
        events
    )
    assert {e["from"] for e in states} == {"alpha"}
    sent = [e for e in events if e["event"] == "sent"]
    assert sent and all(e["mac_len"] == mac_len and e["rc"] == 0 for e in sent)
    acked = next(e for e in states if e["last_command_seq"] == 1)
    assert acked["state"] in (M.TAKEOFF, M.MISSION)
    assert events[-1] == {"event": "done", "state": M.MISSION, "last_command_seq": 1}
    # the Python agent flies what the C node asked for: airborne at the C node's 4 m
    assert probe.wait("alpha/HLC_STATE", "hlc_state_t", timeout=20, state=H.AIRBORNE), agent.log("hlc")
    assert probe.wait("alpha/TELEMETRY", "telemetry_t", timeout=20, in_air=True)
    # AIRBORNE is declared at 95 % of the target: give the climb time to settle before reading it
    deadline = time.monotonic() + 15
    alt = probe.history("alpha/TELEMETRY", "telemetry_t")[-1]["alt"]
    while abs(alt - 4.0) > 0.6 and time.monotonic() < deadline:
        time.sleep(0.2)
        alt = probe.history("alpha/TELEMETRY", "telemetry_t")[-1]["alt"]
    assert alt == pytest.approx(4.0, abs=0.6)
    assert "STANDBY -> TAKEOFF" in agent.log("mc")


def test_c_node_takes_off_a_keyless_agent(
    c_node: Path, netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    agent = AgentProcesses(netns, tmp_path, agent_config("alpha", security={"insecure": True}))
    try:
        agent.start("hlc")
        agent.start("mc")
        code, events, stderr = run_c_node(netns, c_node, key=None)
        assert_flew(code, events, stderr, probe, agent, mac_len=0)
        assert all(not e["signed"] for e in events if e["event"] == "mc_state")
    finally:
        agent.stop()


def test_c_node_signs_for_a_keyed_agent_and_a_wrong_key_is_refused(
    c_node: Path, netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    agent = AgentProcesses(
        netns, tmp_path, agent_config("alpha", security={"swarm_key": KEY, "state_dir": str(tmp_path)})
    )
    try:
        agent.start("hlc")
        agent.start("mc")
        # a C node with another key, then one that does not sign: the MC drops both and stays put
        for key, why in (("not-the-swarm-key", "bad MAC"), (None, "unsigned message")):
            code, events, stderr = run_c_node(netns, c_node, key=key, ack_timeout=3)
            assert code == 1 and events[-1]["event"] == "timeout", f"{events}\n{stderr}"
            assert events[-1]["state"] == M.STANDBY and events[-1]["last_command_seq"] == 0

            def dropped(why: str = why) -> bool:
                return (
                    f"dropped operator_cmd_t on alpha/OPERATOR_CMD from 'c-node' seq 1: {why}"
                    in agent.log("mc")
                )

            assert wait_for(dropped, 10), agent.log("mc")
        assert agent.alive("mc") and agent.alive("hlc")
        # the right key: accepted and flown; the agent's own state messages are signed too
        code, events, stderr = run_c_node(netns, c_node, key=KEY)
        assert_flew(code, events, stderr, probe, agent, mac_len=32)
        assert all(e["signed"] for e in events if e["event"] == "mc_state")
    finally:
        agent.stop()
