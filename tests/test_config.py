"""Config loading: every invalid file stops with the file, the key and what was expected."""

from __future__ import annotations

from pathlib import Path

import pytest

from antalate_lcm.config import load_config, parse_config
from antalate_lcm.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "agent.toml"
    p.write_text(text)
    return p


def test_defaults_are_one_simulated_agent_with_an_anonymous_name() -> None:
    a, b = load_config(None), load_config(None)
    assert a.hlc.autopilot == "sim"
    assert a.agent.name.startswith("anon-") and a.agent.name != b.agent.name
    assert a.topic_buses("MC_STATE") == ["lan"]


def test_full_file(tmp_path: Path) -> None:
    cfg = load_config(
        write(
            tmp_path,
            """
[agent]
name = "alpha"
[buses]
lan = "udpm://239.255.76.67:7667?ttl=1"
local = "udpm://239.255.76.67:7668?ttl=0"
[topics]
default_bus = "local"
MC_STATE = ["local", "lan"]
OPERATOR_CMD = "lan"
VELOCITY_CMD = { bus = "local", channel = "{agent}/VEL" }
SWARM_MODE = { type = "behavior_state_t", channel = "{agent}/SWARM_MODE" }
[hlc]
autopilot = "sim"
[hlc.autopilot_params]
home_lat = 32.1
""",
        )
    )
    assert cfg.agent.name == "alpha"
    assert cfg.topic_buses("MC_STATE") == ["local", "lan"]
    assert cfg.topic_buses("TELEMETRY") == ["local"]
    specs = cfg.topic_specs()
    assert specs["VELOCITY_CMD"].channel == "{agent}/VEL"
    assert specs["SWARM_MODE"].msg_type.__name__ == "behavior_state_t"
    assert cfg.hlc.autopilot_params == {"home_lat": 32.1}


def test_design_style_autopilot_table(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, '[hlc.autopilot]\nname = "tello"\nhost = "192.168.10.1"\n'))
    assert cfg.hlc.autopilot == "tello"
    assert cfg.hlc.autopilot_params == {"host": "192.168.10.1"}


@pytest.mark.parametrize(
    ("text", "key", "expected"),
    [
        ("[hlc]\ntelemetry_hz = 'fast'\n", "hlc.telemetry_hz", "valid number"),
        ("[hlc]\ntelemetry_hz = -1\n", "hlc.telemetry_hz", "greater than 0"),
        ("[hlc]\nlow_battery = 150\n", "hlc.low_battery", "less than or equal to 100"),
        ("[hlc]\nairborne_fraction = nan\n", "hlc.airborne_fraction", ""),
        ("[mc]\ntakeof_ack_timeout = 3\n", "mc.takeof_ack_timeout", "Extra inputs"),
        ("[agent]\nname = 'a b'\n", "agent.name", "white space"),
        ("[agent]\nname = 'drône'\n", "agent.name", "ASCII"),
        ("[buses]\nlan = 'localhost:7667'\n", "buses", "LCM URL"),
        ("[topics]\nMC_STATE = 'wan'\n", "topics.MC_STATE.bus", "declared in [buses]"),
        ("[topics]\ndefault_bus = 'wan'\n", "topics.default_bus", "declared in [buses]"),
        ("[topics]\nFOO = 'lan'\n", "topics.FOO", "known topic"),
        ("[topics]\nFOO = { type = 'nope_t', channel = 'x' }\n", "topics.FOO.type", "one of"),
        ("[[bma]]\nname = 'a'\nstate_topic = 'NOPE'\n", "bma[0].state_topic", "topic name"),
        ("[[bma]]\nname = 'a'\n[[bma]]\nname = 'a'\n", "bma.name", "unique"),
        ("[[bma]]\nname = 'a'\n[[bma.behaviors]]\nactivate_on = ['MISSION']\n", "bma[0].behaviors[0].plugin", "required"),
        ("[osc]\nrate = 0\n", "osc.rate", "greater than 0"),
    ],
)
def test_invalid_files_name_file_key_and_expectation(tmp_path: Path, text: str, key: str, expected: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    err = info.value
    assert err.file == str(path)
    assert err.key == key
    assert expected in err.expected
    assert str(path) in str(err) and key in str(err)


def test_not_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[agent\nname=1"))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.toml")


def test_cli_reports_a_bad_config_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from antalate_lcm.cli import main

    path = write(tmp_path, "[hlc]\nlow_battery = 150\n")
    assert main(["spy", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hlc.low_battery" in err[0] and str(path) in err[0]


def test_parse_config_keeps_a_given_name() -> None:
    assert parse_config({"agent": {"name": "bravo"}}).agent.name == "bravo"


@pytest.mark.parametrize("example", sorted((REPO / "examples").glob("*.toml")), ids=lambda p: p.name)
def test_examples_are_valid(example: Path) -> None:
    from antalate_lcm.runtime.agent import validate

    validate(load_config(example))  # plugins and their params too
