"""The image's health check (containers/healthcheck.py) against real nodes, without a container:
it reads the node's command line, listens for the node's own messages, or asks the station."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from types import ModuleType

import pytest

from tests import REPO
from tests.conftest import Probe
from tests.harness.agents import AgentProcesses, agent_config
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.process import stop_process

pytestmark = pytest.mark.netns

HEALTHCHECK = REPO / "containers" / "healthcheck.py"


def health(ns: NetNamespace, cmdline: str, listen: float = 3.0) -> tuple[int, str]:
    proc = ns.run(
        [sys.executable, str(HEALTHCHECK), "--cmdline", cmdline, "--listen", str(listen)],
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        timeout=60,
    )
    return proc.returncode, (proc.stdout + proc.stderr).strip()


def test_a_running_mc_is_healthy_and_a_missing_hlc_is_not(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    agent = AgentProcesses(
        netns, tmp_path, agent_config("alpha", security={"insecure": True}, bma=[{"name": "swarm"}])
    )
    try:
        agent.start("mc")
        agent.start("bma", "--name", "swarm")
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=20)
        assert health(netns, f"/opt/antalate/bin/python /opt/antalate/bin/antalate mc {agent.path}") == (
            0,
            "healthy",
        )
        assert health(netns, f"antalate bma {agent.path} --name swarm") == (0, "healthy")
        code, said = health(netns, f"antalate hlc {agent.path}")
        assert code == 1 and said == (
            "unhealthy: HLC_STATE not heard (alpha/HLC_STATE) on udpm://239.255.76.67:7667?ttl=0 in 3 s"
        ), said
        code, said = health(netns, f"antalate bma {agent.path} --name other")
        assert code == 1 and "alpha/ARBITER/other" in said, said
        agent.kill("mc")
        code, said = health(netns, f"antalate mc {agent.path}")
        assert code == 1 and said.startswith("unhealthy: MC_STATE not heard"), said
    finally:
        agent.stop()


def test_the_station_answers_or_is_reported(netns: NetNamespace, tmp_path: Path) -> None:
    log = open(tmp_path / "station.log", "w")  # noqa: SIM115 - closed below
    station = netns.antalate("station", "--db", ":memory:", "--port", "8181", stdout=log, stderr=log)
    try:
        assert wait_for(lambda: health(netns, "antalate station --db :memory: --port 8181", 1)[0] == 0, 30), (
            tmp_path / "station.log"
        ).read_text()
        code, said = health(netns, "antalate station --port 8182", 1)
        assert code == 1 and "the station does not answer on http://127.0.0.1:8182/api/station" in said, said
    finally:
        stop_process(station)
        log.close()


def test_a_config_that_does_not_load_or_a_foreign_command_is_unhealthy(
    netns: NetNamespace, tmp_path: Path
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[hlc]\nlow_battery = 150\n")
    code, said = health(netns, f"antalate mc {bad}")
    assert code == 1 and "hlc.low_battery" in said, said
    code, said = health(netns, "sleep 100")
    assert code == 1 and said.startswith("unhealthy: not an antalate command line"), said
    assert health(netns, "antalate keygen") == (0, "healthy (antalate keygen)")


def load_healthcheck() -> ModuleType:
    import importlib.util

    spec = importlib.util.spec_from_file_location("antalate_healthcheck", HEALTHCHECK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_what_is_checked_for_each_command_line(tmp_path: Path) -> None:
    """Pure: the plan read from a command line (no bus, no HTTP)."""
    import re

    import tomli_w

    hc = load_healthcheck()
    cfg = tmp_path / "alpha.toml"
    cfg.write_text(tomli_w.dumps(agent_config("alpha", security={"insecure": True})))
    swarm = hc.plan(
        ["/opt/antalate/bin/python", "/opt/antalate/bin/antalate", "agent", str(cfg), "--agents", "3"]
    )
    assert isinstance(swarm, hc.LcmCheck) and swarm.urls == ("udpm://239.255.76.67:7667?ttl=0",)
    assert re.fullmatch(swarm.channel_regex, "alpha-02/MC_STATE") and not re.fullmatch(
        swarm.channel_regex, "beta/MC_STATE"
    )
    station_toml = tmp_path / "station.toml"
    station_toml.write_text('[station]\nhost = "0.0.0.0"\nport = 9090\n')
    assert hc.plan(["antalate", "station", "--config", str(station_toml)]) == hc.HttpCheck(
        "http://127.0.0.1:9090/api/station", "the station"
    )
    assert hc.plan(
        ["antalate", "station", "--port", "8443", "--tls-cert", "c.pem", "--tls-key", "k.pem"]
    ).url == ("https://127.0.0.1:8443/api/station")
    assert hc.plan(["antalate", "tui", "--web", "--port", "8001"]) == hc.HttpCheck(
        "http://127.0.0.1:8001/login", "the web console"
    )
    assert isinstance(hc.plan(["python", "-m", "antalate_lcm.cli", "tui"]), hc.NothingToCheck)
    memq = tmp_path / "memq.toml"
    memq.write_text('[agent]\nname = "m"\n[buses]\nlan = "memq://"\n')
    assert isinstance(hc.plan(["antalate", "mc", str(memq)]), hc.NothingToCheck)
