"""The antalate command as a user meets it: clear one-line errors, nothing started on a bad config."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.netns import netns_unavailable

REPO = Path(__file__).resolve().parent.parent


def antalate(*args: str, timeout: float = 60, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", *args], capture_output=True, text=True, timeout=timeout, **kw
    )  # type: ignore[call-overload]


def test_help_lists_every_command() -> None:
    out = antalate("--help").stdout
    for cmd in ("mc", "hlc", "bma", "osc", "agent", "station", "demo", "spy"):
        assert cmd in out


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[hlc]\nlow_battery = 150\n", "hlc.low_battery"),
        ('[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "no_such_behavior"\nactivate_on = ["MISSION"]\n', "no_such_behavior"),
        ('[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "auto_operator"\nactivate_on = ["FLYING"]\n', "FLYING"),
        ('[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "auto_operator"\nparams = { retry = -1 }\n', "retry"),
        ('[hlc]\nautopilot = "warp_drive"\n', "warp_drive"),
    ],
)
@pytest.mark.parametrize("command", ["agent", "mc"])
def test_bad_config_stops_before_any_node_starts(tmp_path: Path, text: str, needle: str, command: str) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[buses]\nlan = "memq://"\n' + text)
    proc = antalate(command, str(cfg))
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("antalate: ") and needle in lines[-1], proc.stderr
    assert "Traceback" not in proc.stderr
    assert "started" not in proc.stderr, "no node may start on an invalid config"


def test_missing_config_file(tmp_path: Path) -> None:
    proc = antalate("hlc", str(tmp_path / "nope.toml"))
    assert proc.returncode == 2 and "file not found" in proc.stderr


def test_unknown_arbiter_name() -> None:
    proc = antalate("bma", str(REPO / "examples" / "sim_swarm.toml"), "--name", "nope")
    assert proc.returncode == 2 and "no [[bma]] named 'nope'" in proc.stderr and "swarm" in proc.stderr


def test_duplicate_agent_names(tmp_path: Path) -> None:
    cfg = tmp_path / "a.toml"
    cfg.write_text('[agent]\nname = "same"\n[buses]\nlan = "memq://"\n')
    proc = antalate("agent", str(cfg), str(cfg))
    assert proc.returncode == 2 and "share the name" in proc.stderr


def test_agents_n_needs_the_sim(tmp_path: Path) -> None:
    cfg = tmp_path / "t.toml"
    cfg.write_text('[buses]\nlan = "memq://"\n[hlc]\nautopilot = "tello"\n')
    proc = antalate("agent", str(cfg), "--agents", "3")
    assert proc.returncode == 2 and "--agents N" in proc.stderr


def test_no_multicast_route_is_one_clear_message(tmp_path: Path) -> None:
    reason = netns_unavailable()
    if reason:
        pytest.skip(f"no private network namespace: {reason}")
    proc = subprocess.run(
        ["unshare", "-rn", sys.executable, "-m", "antalate_lcm.cli", "mc", str(REPO / "examples" / "sim_agent.toml")],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2
    assert "ip route add 224.0.0.0/4 dev lo" in proc.stderr and "memq://" in proc.stderr
    assert "Traceback" not in proc.stderr and "Couldn't create LCM" not in proc.stderr


def test_agent_runs_and_stops_cleanly_on_sigterm(tmp_path: Path) -> None:
    import signal
    import time

    cfg = tmp_path / "a.toml"
    cfg.write_text('[agent]\nname = "solo"\n[buses]\nlan = "memq://"\n')
    proc = subprocess.Popen(
        [sys.executable, "-m", "antalate_lcm.cli", "agent", str(cfg), "--agents", "3"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    time.sleep(3)
    assert proc.poll() is None
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "INIT -> STANDBY" in err and "solo-03" in err
