"""The antalate command as a user meets it: clear one-line errors, nothing started on a bad config."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests import REPO
from tests.harness.netns import netns_unavailable


def antalate(*args: str, timeout: float = 60, **kw: Any) -> subprocess.CompletedProcess[str]:
    """``kw`` are subprocess.run's."""
    done: subprocess.CompletedProcess[str] = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        **kw,
    )
    return done


def test_help_lists_every_command() -> None:
    out = antalate("--help").stdout
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
        antalate("agent", str(cfg), env=env),
        f"invalid config {cfg}: hlc.autopilot: expected an installed adapter (crazyflie, mavlink, px4, sim, tello)",
        "No module named 'serial_port_that_is_not_here'",
    )


def test_duplicate_agent_names(tmp_path: Path) -> None:
    a, b, c = tmp_path / "a.toml", tmp_path / "b.toml", tmp_path / "c.toml"
    a.write_text('[agent]\nname = "same"\n[buses]\nlan = "memq://"\n')
    b.write_text('[buses]\nlan = "memq://"\n')
    c.write_text('[buses]\nlan = "memq://"\n')
    one_line_error(
        antalate("agent", str(a), str(a)),
        f"invalid config {a}: agent.name: ",
        "'same'",
        "the same file twice",
    )
    # --agents 2 names the copies of an unnamed agent sim-01, sim-02: two such configs collide
    one_line_error(
        antalate("agent", str(b), str(c), "--agents", "2"),
        f"invalid config {c}: agent.name: ",
        "'sim-01' is also an agent of",
        str(b),
        "--agents 2",
    )


@pytest.mark.parametrize(
    ("text", "key", "expected"),
    [
        ('[hlc]\ntelemetry_hz = "5"\n', "hlc.telemetry_hz", "valid number, got '5'"),
        ('[osc]\nenabled = "yes"\n', "osc.enabled", "valid boolean, got 'yes'"),
        ('[buses]\nlan = "http://127.0.0.1:8080"\n', "buses.lan", "not 'http://'"),
        ('[buses]\nlan = "udpm://239.255.76.67:99999"\n', "buses.lan", "a port 1-65535"),
        ('[buses]\nlan = "udpm://10.0.0.7:7667"\n', "buses.lan", "multicast group"),
        (
            '[hlc]\nautopilot = ":Foo"\n',
            "hlc.autopilot",
            "an installed adapter (crazyflie, mavlink, px4, sim, tello)",
        ),
        (
            '[hlc]\nautopilot = ".sim:X"\n',
            "hlc.autopilot",
            "an installed adapter (crazyflie, mavlink, px4, sim, tello)",
        ),
        ('[hlc]\nautopilot = "nope"\n', "hlc.autopilot", "there is no adapter 'nope'"),
        (
            '[hlc]\nautopilot = "antalate_lcm.no_such:X"\n',
            "hlc.autopilot",
            "No module named 'antalate_lcm.no_such'",
        ),
        (
            '[hlc]\nautopilot = "antalate_lcm.autopilot.base:AutopilotState"\n',
            "hlc.autopilot",
            "not a subclass",
        ),
        ('[security]\nwindow = "5"\n', "security.window", "valid number, got '5'"),
        ('[topics]\nMC_STATE = { bus = "lan", channel = 7 }\n', "topics.MC_STATE.channel", "valid string"),
        (
            '[hlc.autopilot]\nname = "sim"\nland_disarm_delay = -1\n',
            "hlc.autopilot.land_disarm_delay",
            "greater than or equal to 0",
        ),
        ('[osc]\nserver = "ftp://station"\n', "osc.server", "an http:// or https:// URL"),
        (
            '[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = "auto_operator"\nparams = { retry = "2" }\n',
            "bma[0].behaviors[0].params.retry",
            "valid number",
        ),
        (
            '[[bma]]\nname = "x"\n[[bma.behaviors]]\nplugin = ".auto_operator:X"\n',
            "bma[0].behaviors[0].plugin",
            "package.module:ClassName",
        ),
    ],
)
def test_config_mistakes_are_one_line_naming_file_key_and_expectation(
    tmp_path: Path, text: str, key: str, expected: str
) -> None:
    cfg = tmp_path / "field.toml"
    cfg.write_text(text if "[buses]" in text else '[buses]\nlan = "memq://"\n' + text)
    one_line_error(antalate("agent", str(cfg)), f"antalate: invalid config {cfg}: {key}: ", expected)


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
        [
            "unshare",
            "-rn",
            sys.executable,
            "-m",
            "antalate_lcm.cli",
            "mc",
            str(REPO / "examples" / "sim_agent.toml"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "ip route add 224.0.0.0/4 dev lo" in proc.stderr and "memq://" in proc.stderr
    assert "Traceback" not in proc.stderr and "Couldn't create LCM" not in proc.stderr


def test_agent_runs_and_stops_cleanly_on_sigterm(tmp_path: Path) -> None:
    import queue
    import signal
    import threading
    import time

    cfg = tmp_path / "a.toml"
    cfg.write_text('[agent]\nname = "solo"\n[buses]\nlan = "memq://"\n')
    proc = subprocess.Popen(
        [sys.executable, "-m", "antalate_lcm.cli", "agent", str(cfg), "--agents", "3"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: queue.Queue[str] = queue.Queue()
    assert proc.stderr is not None
    stderr = proc.stderr

    def pump() -> None:
        for ln in stderr:
            lines.put(ln)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    standby: set[str] = set()
    seen: list[str] = []
    deadline = time.monotonic() + 60
    try:
        # every agent reaches STANDBY (its MC heard its HLC): the whole process is up
        while standby != {"solo-01", "solo-02", "solo-03"} and time.monotonic() < deadline:
            try:
                line = lines.get(timeout=0.5)
            except queue.Empty:
                assert proc.poll() is None, "".join(seen)
                continue
            seen.append(line)
            if "INIT -> STANDBY" in line:
                standby.update(n for n in ("solo-01", "solo-02", "solo-03") if n in line)
        assert standby == {"solo-01", "solo-02", "solo-03"}, "".join(seen)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0, "".join(seen)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=5)


def test_no_multicast_route_message_only_when_the_route_is_missing() -> None:
    """In a namespace that routes only 239.255.76.68 (an agent's own bus, docs/lan.md) to lo."""
    import json

    reason = netns_unavailable()
    if reason:
        pytest.skip(f"no private network namespace: {reason}")
    urls = [
        "udpm://239.255.76.67:7667?ttl=0",  # valid, not routed: the route message
        "udpm://239.255.76.68:7668?ttl=0",  # valid, routed: opens
        "udpm://239.255.76.68:99999",  # routed group, impossible port
        "udpm://10.0.0.1:7667",  # not a multicast group (and not routed either)
        "http://127.0.0.1:8080",
        "file:///nonexistent/flight.lcm",
    ]
    script = 'ip link set lo up && ip route add 239.255.76.68/32 dev lo && exec "$0" -m tests.children.open_buses "$@"'
    proc = subprocess.run(
        ["unshare", "-rn", "sh", "-c", script, sys.executable, *urls],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
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
    reason = netns_unavailable()
    if reason:
        pytest.skip(f"no private network namespace: {reason}")
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[buses]\nlan = "udpm://239.255.76.67:99999?ttl=1"\n')
    proc = subprocess.run(
        ["unshare", "-rn", sys.executable, "-m", "antalate_lcm.cli", "mc", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    line = one_line_error(proc, f"invalid config {cfg}: buses.lan: expected a port 1-65535")
    assert "ip route" not in line and "route" not in proc.stderr
