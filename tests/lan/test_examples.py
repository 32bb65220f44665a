"""The LAN example configs are laid out as docs/lan.md says (no network needed: run everywhere)."""

from __future__ import annotations

from urllib.parse import urlparse

import pytest

from antalate_lcm.core.config import load_config
from antalate_lcm.runtime.agent import validate
from tests.lan.swarm import EXAMPLES, OPERATOR, VEHICLES
from tests.lan.topology import LOCAL_GROUP, SUBNET


def _group(url: str) -> tuple[str, int, str]:
    u = urlparse(url)
    return u.hostname or "", u.port or 0, u.query


@pytest.mark.parametrize("name", VEHICLES)
def test_vehicle_configs_keep_the_agents_own_bus_on_the_host(name: str) -> None:
    config = load_config(EXAMPLES / f"{name}.toml")
    validate(config)
    assert config.agent.name == name
    lan, local = _group(config.buses["lan"]), _group(config.buses["local"])
    assert lan[2] == "ttl=1" and local[2] == "ttl=0"
    # its own group, the one the hosts route to lo, and its own port: never confused with the LAN bus
    assert local[0] == LOCAL_GROUP and local[0] != lan[0] and local[1] != lan[1]
    # the agent's nodes listen to each other on local; the operator hears them on the LAN
    for topic in ("MC_STATE", "HLC_STATE", "TELEMETRY", "HLC_ERROR", "ARBITER"):
        assert config.topic_buses(topic) == ["local", "lan"], topic
    for topic in ("VELOCITY_CMD", "OPERATOR_PAYLOAD", "OPERATOR_FEEDBACK"):
        assert config.topic_buses(topic) == ["local"], topic
    for topic in ("OPERATOR_CMD", "DIRECTION_CMD", "SWARM_OPERATOR_CMD", "SWARM_DIRECTION_CMD"):
        assert config.topic_buses(topic)[0] == "lan", topic
    # the station runs on the operator host of the simulated LAN (the last host: .10 + 6)
    assert config.osc.enabled and config.osc.server == f"http://{SUBNET}.{10 + len(VEHICLES) + 1}:8080"
    assert [b.name for b in config.bma] == ["swarm"]


def test_vehicles_have_distinct_homes_and_the_operator_only_the_lan() -> None:
    homes = {
        (c.hlc.autopilot_params["home_lat"], c.hlc.autopilot_params["home_lon"])
        for c in (load_config(EXAMPLES / f"{n}.toml") for n in VEHICLES)
    }
    assert len(homes) == len(VEHICLES)
    op = load_config(EXAMPLES / f"{OPERATOR}.toml")
    assert op.agent.name == OPERATOR and set(op.buses) == {"lan"}
    assert op.buses["lan"] == load_config(EXAMPLES / "uav-1.toml").buses["lan"]
