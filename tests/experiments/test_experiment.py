"""``antalate run`` (one-command experiments) and ``antalate new behavior`` (the template generator).

The flights are real: agents, MC, HLC and BMA nodes on a real bus (``memq://`` in one process, udpm
multicast inside a private network namespace across processes), the generated package built and
installed by pip, and the recorded log read back by the analysis.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from antalate_lcm.apps.analysis import analyze_log, read_log
from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.cli import main
from antalate_lcm.runtime.experiment import Experiment, run
from antalate_lcm.runtime.scaffold import files, write_behavior
from antalate_lcm.runtime.script import load_script, parse_script
from tests import REPO
from tests.harness.agents import swarm_config
from tests.harness.cases import cases

MEMQ_CONFIG = swarm_config("e", {"plugin": "direction_follow"})


@pytest.fixture
def config(tmp_path: Path) -> Path:
    """The swarm of the flights in one process: ``direction_follow`` on ``memq://``."""
    path = tmp_path / "swarm.toml"
    path.write_text(MEMQ_CONFIG)
    return path


# ----------------------------------------------------------------------------- the script
@pytest.mark.parametrize(("text", "key", "what"), cases("experiments/bad_scripts.toml"))
def test_a_bad_script_is_one_line_naming_the_key(tmp_path: Path, text: str, key: str, what: str) -> None:
    path = tmp_path / "script.toml"
    path.write_text(text + "\n")
    with pytest.raises(ConfigError) as info:
        load_script(path)
    assert info.value.key == key and what in str(info.value), str(info.value)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_script_defaults_and_a_full_script() -> None:
    assert load_script(None).mission_time == 30.0 and load_script(None).direction == ()
    s = parse_script(
        {
            "mission_time": 20,
            "altitude": 8,
            "direction": [{"at": 0, "azimuth": 90}, {"at": 5, "azimuth": 0, "active": False}],
            "analyze": {"range": 15, "radius_below": 5},
        },
        "s.toml",
    )
    assert [(d.at, d.azimuth, d.speed, d.active) for d in s.direction] == [
        (0, 90, 1.0, True),
        (5, 0, 1.0, False),
    ]
    assert (s.analyze.range_m, s.analyze.radius_below, s.analyze.radius_above) == (15, 5, None)


# ----------------------------------------------------------------------------- refusals before flight
def test_bad_configs_and_options_fail_before_anything_flies(
    tmp_path: Path, config: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.lcm"
    # agents in other processes cannot hear an operator on memq://: the key, not a silent no-show
    assert main(["run", str(config), "--agents", "2", "--processes", "2", "--headless", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "buses.lan" in err and "--processes 2" in err
    bad_plugin = tmp_path / "bad.toml"
    bad_plugin.write_text(swarm_config("e", {"plugin": "no_such_behavior"}))
    assert main(["run", str(bad_plugin), "--headless", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bma[0].behaviors[0].plugin" in err
    out.write_bytes(b"")
    assert main(["run", str(config), "--headless", "-o", str(out)]) == 2
    assert "exists: pass --force" in capsys.readouterr().err
    assert main(["run", str(config), "--headless", "--bus", "nope", "-o", str(tmp_path / "y.lcm")]) == 2
    assert "no bus named 'nope'" in capsys.readouterr().err
    assert not (tmp_path / "y.lcm").exists()
    with pytest.raises(AntalateError, match="--agents wants a number >= 1"):
        run(Experiment(str(config), agents=0, output=str(tmp_path / "z.lcm")))


# ----------------------------------------------------------------------------- a flight in one process
def test_run_flies_the_script_records_and_prints_the_metrics(
    tmp_path: Path, config: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = tmp_path / "script.toml"
    script.write_text(
        "mission_time = 8.0\n"
        "[[direction]]\nat = 1.0\nazimuth = 90.0\nspeed = 2.0\n"
        "[[direction]]\nat = 5.0\nazimuth = 0.0\nactive = false\n"
        "[analyze]\nrange = 20.0\nradius_below = 1.0\n"
    )
    out = tmp_path / "flight.lcm"
    code = main(
        ["--log-level", "WARNING", "run", str(config), "--agents", "4", "--headless"]
        + ["--script", str(script), "-o", str(out)]
    )
    text = capsys.readouterr().out
    assert code == 0, text
    assert "OK: 4 agent(s), all back in STANDBY" in text
    assert "phase mission:" in text and "radius first below 1 m: never" in text
    assert "connectivity 20 m  connected in 100 % of the samples" in text
    result = analyze_log(out, range_m=20.0)
    assert sorted(result.tracks) == ["e-01", "e-02", "e-03", "e-04"]
    # the scripted directions are in the log: east at 2 m/s, then a stop 4 s later
    record = read_log(out)
    assert [(d.active, d.azimuth, d.speed) for d in record.directions] == [
        (True, 90.0, 2.0),
        (False, 0.0, 1.0),
    ]
    (d,) = result.drift  # the span under the active command only
    assert d.heading is not None and d.error is not None and abs(d.error) < 10.0
    mission = result.phase("mission")
    assert mission is not None and mission.polarisation is not None and mission.polarisation.max > 0.9
    assert [p.phase.name for p in result.phases] == ["takeoff", "mission", "return"]
    # homes 8 m apart on a 2 x 2 grid, all flown the same way: the square holds
    assert mission.min_separation is not None and mission.min_separation.distance == pytest.approx(
        8.0, abs=0.5
    )


def test_a_shipped_peer_rule_flies_in_one_process_on_memq(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """examples/swarm_rules/flocking.toml as shipped (memq://, no swarm key): the whole swarm is in
    this process, so a peer behavior hears its peers and is not refused as a split swarm."""
    example = REPO / "examples" / "swarm_rules" / "flocking.toml"
    script = tmp_path / "script.toml"
    script.write_text("mission_time = 4.0\n[analyze]\nrange = 30.0\n")
    out = tmp_path / "flock.lcm"
    code = main(
        ["--log-level", "WARNING", "run", str(example), "--agents", "3", "--spacing", "6", "--headless"]
        + ["--script", str(script), "-o", str(out)]
    )
    text = capsys.readouterr().out
    assert code == 0, text
    assert "OK: 3 agent(s), all back in STANDBY" in text
    mission = analyze_log(out).phase("mission")  # they flew: the rule heard its peers and moved
    assert mission is not None and mission.polarisation is not None and mission.polarisation.max > 0.9


# ----------------------------------------------------------------------------- antalate new behavior
def test_new_behavior_refuses_bad_names_and_existing_folders(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in ("My-Thing", "1st", "class", "a b", ""):
        assert main(["new", "behavior", name, "--dir", str(tmp_path)]) == 2
        assert "behavior name" in capsys.readouterr().err
    write_behavior("twice", tmp_path)
    assert main(["new", "behavior", "twice", "--dir", str(tmp_path)]) == 2
    assert "exists" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "twice").iterdir()) == sorted(
        {"pyproject.toml", "README.md", "config.toml", "script.toml", "twice", "tests"}
    )
    # the generated config and script pass antalate's own validation, unchanged
    from antalate_lcm.core.config import load_config

    assert load_config(tmp_path / "twice" / "config.toml").bma[0].behaviors[0].plugin == "twice"
    assert load_script(tmp_path / "twice" / "script.toml").mission_time == 20.0
    assert set(files("x")) >= {"x/logic.py", "x/behavior.py", "tests/test_logic.py"}


@pytest.mark.netns
def test_a_generated_behavior_installs_and_flies_across_processes(netns, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """`antalate new behavior`, pip install (built by its own pyproject), its test, then
    `antalate run --headless` with 3 agents over 2 processes on multicast in a namespace."""
    assert main(["new", "behavior", "spiral_test", "--dir", str(tmp_path)]) == 0
    pkg = tmp_path / "spiral_test"
    site = tmp_path / "site"
    pip = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(pkg)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if pip.returncode != 0 and "No matching distribution found for setuptools" in pip.stderr:
        pytest.skip("pip cannot fetch setuptools to build the package (no package index reachable)")
    assert pip.returncode == 0, pip.stderr
    entry_points = next(site.glob("spiral_test-*.dist-info")) / "entry_points.txt"
    assert "spiral_test = spiral_test.behavior:SpiralTest" in entry_points.read_text()
    env_path = f"{site}"
    own_test = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(pkg / "tests")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**_env(), "PYTHONPATH": env_path},
        timeout=120,
    )
    assert own_test.returncode == 0 and "1 passed" in own_test.stdout, own_test.stdout + own_test.stderr
    (pkg / "short.toml").write_text("mission_time = 4.0\n[analyze]\nrange = 30.0\n")
    log = tmp_path / "flight.lcm"
    argv = [sys.executable, "-m", "antalate_lcm.cli", "--log-level", "WARNING", "run", "config.toml"]
    argv += ["--agents", "3", "--processes", "2", "--headless", "--script", "short.toml", "-o", str(log)]
    from tests.harness.process import child_env

    env = child_env()
    env["PYTHONPATH"] = f"{site}:{env['PYTHONPATH']}"
    flight = netns.run(argv, timeout=180, cwd=pkg, env=env)
    assert flight.returncode == 0, flight.stdout + flight.stderr
    assert "OK: 3 agent(s), all back in STANDBY" in flight.stdout
    assert "phase mission:" in flight.stdout
    record = read_log(log)
    assert sorted(record.agents) == ["spiral-test-01", "spiral-test-02", "spiral-test-03"]
    for name, agent in record.agents.items():
        states = [c.state for c in agent.mc_states]
        assert "MISSION" in states and states[-1] == "STANDBY", (name, states)
        assert not agent.telemetry[-1].in_air, name  # landed
    # it flew its circle: 2 m/s while in the mission
    mission = analyze_log(log).phase("mission")
    assert mission is not None and mission.polarisation is not None and mission.polarisation.max > 0.9


def _env() -> dict[str, str]:
    from tests.harness.process import child_env

    return child_env()


# ----------------------------------------------------------------------------- with the console
def test_run_with_the_console_in_a_real_terminal(tmp_path: Path, config: Path) -> None:
    """Without --headless the operator console flies (tmux: take off all, RTL all, quit); the log
    and the metrics follow when it quits."""
    import shlex
    import shutil

    from tests.harness.polling import wait_for
    from tests.harness.tmux import Tmux, fly_one_sortie

    if shutil.which("tmux") is None:
        pytest.skip("tmux is not installed (Debian/Ubuntu: apt-get install tmux)")
    log = tmp_path / "console.lcm"
    argv = [sys.executable, "-m", "antalate_lcm.cli", "run", str(config), "--agents", "2", "-o", str(log)]
    env = _env()
    # TMPDIR: the nodes' log file (named at the end) stays in the test's folder
    where = shlex.quote(str(tmp_path))
    cmd = f"cd {where} && TMPDIR={where} PYTHONPATH={shlex.quote(env['PYTHONPATH'])} {shlex.join(argv)}"
    cmd += "; echo RUN-EXITED-$?; sleep 60"
    with Tmux(cmd, session="run") as term:
        fly_one_sortie(term, "e-0", 2)
        term.keys("q")
        assert wait_for(lambda: "RUN-EXITED-0" in term.screen(200), 30), term.screen(200)
        assert "phase mission:" in term.screen(200)
    (node_log,) = tmp_path.glob("antalate-run-*.log")
    assert "antalate.mc.e-01" in node_log.read_text()  # the nodes' lines went there, not on the console
    record = read_log(log)
    assert sorted(record.agents) == ["e-01", "e-02"]
    assert all("MISSION" in [c.state for c in a.mc_states] for a in record.agents.values())


def test_ctrl_c_mid_mission_stops_cleanly_and_still_measures(tmp_path: Path, config: Path) -> None:
    """SIGINT while the swarm is in MISSION: the nodes stop in order, the log is complete up to
    there, the metrics are printed (here as --json), exit status 130."""
    import signal

    from tests.harness.polling import wait_for
    from tests.harness.process import stop_process

    script = tmp_path / "long.toml"
    script.write_text("mission_time = 600.0\n")
    log = tmp_path / "cut.lcm"
    argv = [sys.executable, "-m", "antalate_lcm.cli", "run", str(config), "--agents", "2", "--headless"]
    proc = subprocess.Popen(
        [*argv, "--json", "--script", str(script), "-o", str(log)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        start_new_session=True,
    )
    try:
        # the operator logs each phase; MISSION once every agent is in it
        assert proc.stderr is not None
        lines: list[str] = []

        def in_mission() -> bool:
            line = proc.stderr.readline() if proc.stderr is not None else ""
            lines.append(line)
            return "phase: mission" in line

        assert wait_for(in_mission, 60), "".join(lines)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        stop_process(proc)
    assert proc.returncode == 130, out
    data = json.loads(out)
    assert (data["ok"], data["code"], data["log"]) == (False, 130, str(log))
    assert all(any(s["state"] == "MISSION" for s in tl) for tl in data["timelines"].values())
    assert len(data["timelines"]) == 2 and data["messages"] > 0
    assert [p["phase"]["name"] for p in data["analysis"]["phases"]] == ["takeoff", "mission"]
    record = read_log(log)
    assert all("MISSION" in [c.state for c in a.mc_states] for a in record.agents.values())
