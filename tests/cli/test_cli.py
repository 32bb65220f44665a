"""The antalate command as a user meets it: clear one-line errors, nothing started on a bad config."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests import REPO
from tests.harness.cases import cases
from tests.harness.netns import run_unrouted
from tests.harness.polling import wait_for
from tests.harness.process import OutputLines, antalate_argv, run_antalate


def test_help_lists_every_command() -> None:
    out = run_antalate("--help").stdout
    for cmd in ("mc", "hlc", "bma", "osc", "agent", "station", "demo", "spy"):
        assert cmd in out


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[hlc]\nlow_battery = 150\n", "hlc.low_battery"),
        (
            '[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "no_such_behavior"\nactivate_on = ["MISSION"]\n',
            "no_such_behavior",
        ),
        (
            '[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "auto_operator"\nactivate_on = ["FLYING"]\n',
            "FLYING",
        ),
        (
            '[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "auto_operator"\nparams = { retry = -1 }\n',
            "retry",
        ),
        ('[hlc]\nautopilot = "warp_drive"\n', "warp_drive"),
    ],
)
@pytest.mark.parametrize("command", ["agent", "mc"])
def test_bad_config_stops_before_any_node_starts(
    tmp_path: Path, text: str, needle: str, command: str
) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[buses]\nlan = "memq://"\n' + text)
    proc = run_antalate(command, str(cfg))
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("antalate: ") and needle in lines[-1], proc.stderr
    assert "Traceback" not in proc.stderr
    assert "started" not in proc.stderr, "no node may start on an invalid config"


def test_missing_config_file(tmp_path: Path) -> None:
    proc = run_antalate("hlc", str(tmp_path / "nope.toml"))
    assert proc.returncode == 2 and "file not found" in proc.stderr


def test_unknown_arbiter_name() -> None:
    proc = run_antalate("bma", str(REPO / "examples" / "sim_swarm.toml"), "--name", "nope")
    assert proc.returncode == 2 and "no [[bma]] named 'nope'" in proc.stderr and "swarm" in proc.stderr


def one_line_error(proc: subprocess.CompletedProcess[str], *needles: str) -> str:
    """The run failed with exit code 2 and one ``antalate: ...`` line holding every needle."""
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("antalate: "), proc.stderr
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_an_adapter_module_that_fails_to_import(tmp_path: Path) -> None:
    import os

    (tmp_path / "field_adapter.py").write_text("import serial_port_that_is_not_here\n")
    cfg = tmp_path / "field.toml"
    cfg.write_text('[buses]\nlan = "memq://"\n[hlc]\nautopilot = "field_adapter:Adapter"\n')
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    one_line_error(
        run_antalate("agent", str(cfg), env=env),
        f"invalid config {cfg}: hlc.autopilot: expected an installed adapter (crazyflie, mavlink, px4, sim, tello)",
        "No module named 'serial_port_that_is_not_here'",
    )


def test_duplicate_agent_names(tmp_path: Path) -> None:
    a, b, c = tmp_path / "a.toml", tmp_path / "b.toml", tmp_path / "c.toml"
    a.write_text('[agent]\nname = "same"\n[buses]\nlan = "memq://"\n')
    b.write_text('[buses]\nlan = "memq://"\n')
    c.write_text('[buses]\nlan = "memq://"\n')
    one_line_error(
        run_antalate("agent", str(a), str(a)),
        f"invalid config {a}: agent.name: ",
        "'same'",
        "the same file twice",
    )
    # --agents 2 names the copies of an unnamed agent sim-01, sim-02: two such configs collide
    one_line_error(
        run_antalate("agent", str(b), str(c), "--agents", "2"),
        f"invalid config {c}: agent.name: ",
        "'sim-01' is also an agent of",
        str(b),
        "--agents 2",
    )


@pytest.mark.parametrize(("text", "key", "expected"), cases("cli/bad_configs.toml"))
def test_config_mistakes_are_one_line_naming_file_key_and_expectation(
    tmp_path: Path, text: str, key: str, expected: str
) -> None:
    cfg = tmp_path / "field.toml"
    cfg.write_text(text if "[buses]" in text else '[buses]\nlan = "memq://"\n' + text)
    one_line_error(run_antalate("agent", str(cfg)), f"antalate: invalid config {cfg}: {key}: ", expected)


def test_agents_n_needs_the_sim(tmp_path: Path) -> None:
    cfg = tmp_path / "t.toml"
    cfg.write_text('[buses]\nlan = "memq://"\n[hlc]\nautopilot = "tello"\n')
    proc = run_antalate("agent", str(cfg), "--agents", "3")
    assert proc.returncode == 2 and "--agents N" in proc.stderr


def test_no_multicast_route_is_one_clear_message(tmp_path: Path) -> None:
    proc = run_unrouted(antalate_argv("mc", str(REPO / "examples" / "sim_agent.toml")))
    assert proc.returncode == 2
    assert "ip route add 224.0.0.0/4 dev lo" in proc.stderr and "memq://" in proc.stderr
    assert "Traceback" not in proc.stderr and "Couldn't create LCM" not in proc.stderr


def test_agent_runs_and_stops_cleanly_on_sigterm(tmp_path: Path) -> None:
    import signal

    cfg = tmp_path / "a.toml"
    cfg.write_text('[agent]\nname = "solo"\n[buses]\nlan = "memq://"\n')
    proc = subprocess.Popen(
        antalate_argv("agent", str(cfg), "--agents", "3"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    err = OutputLines(proc.stderr)
    names = ("solo-01", "solo-02", "solo-03")

    def all_in_standby() -> bool:
        """Every agent reached STANDBY (its MC heard its HLC): the whole process is up."""
        assert proc.poll() is None, err.text()
        return all(any("INIT -> STANDBY" in line and n in line for line in err.lines) for n in names)

    try:
        assert wait_for(all_in_standby, 60), err.text()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0, err.text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err.join()


def test_no_multicast_route_message_only_when_the_route_is_missing() -> None:
    """In a namespace that routes only 239.255.76.68 (an agent's own bus, docs/lan.md) to lo."""
    import json

    urls = [
        "udpm://239.255.76.67:7667?ttl=0",  # valid, not routed: the route message
        "udpm://239.255.76.68:7668?ttl=0",  # valid, routed: opens
        "udpm://239.255.76.68:99999",  # routed group, impossible port
        "udpm://10.0.0.1:7667",  # not a multicast group (and not routed either)
        "http://127.0.0.1:8080",
        "file:///nonexistent/flight.lcm",
    ]
    script = 'ip link set lo up && ip route add 239.255.76.68/32 dev lo && exec "$0" -m tests.children.open_buses "$@"'
    proc = run_unrouted(["sh", "-c", script, sys.executable, *urls], cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got[urls[0]].startswith("MulticastUnavailable: ") and "no route for multicast" in got[urls[0]]
    assert got[urls[1]] == "opened"
    # A malformed URL and an unknown scheme are refused by the registry (both a BusUnavailable).
    assert got[urls[2]].startswith("InvalidBusUrl: ") and "a port 1-65535" in got[urls[2]]
    assert got[urls[3]].startswith("InvalidBusUrl: ") and "multicast group" in got[urls[3]]
    assert got[urls[4]].startswith("UnknownTransport: ") and "not 'http://'" in got[urls[4]]
    assert got[urls[5]].startswith("BusUnavailable: ") and "No such file or directory" in got[urls[5]]
    assert got["routed group, liblcm refused"] == "BusUnavailable"


def test_a_bad_bus_url_without_a_route_is_a_config_error(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[buses]\nlan = "udpm://239.255.76.67:99999?ttl=1"\n')
    proc = run_unrouted(antalate_argv("mc", str(cfg)))
    line = one_line_error(proc, f"invalid config {cfg}: buses.lan: expected a port 1-65535")
    assert "ip route" not in line and "route" not in proc.stderr
