"""Simulated time (``antalate run --speed``), runs that are a function of ``--seed``, ``antalate replay``.

The flights are real: MC, HLC, BMA with ``dovrat_swarm`` and the sim for 20 agents, in one process on
``memq://``, recorded and hashed message by message; the second run of a seed is another process
with another ``PYTHONHASHSEED``, so set order and thread timing cannot hide behind a shared process.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import time
from pathlib import Path

import lcm
import pytest

from antalate_lcm.cli import main
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.simclock import SIM_EPOCH, SIM_START, SimClock
from antalate_lcm.msgs import telemetry_t
from antalate_lcm.runtime.experiment import Experiment, run
from antalate_lcm.runtime.replay import first_divergence, record_path
from antalate_lcm.runtime.script import load_script
from tests.harness.agents import swarm_config
from tests.harness.process import run_antalate

AGENTS = 20


def config(speed: float, autopilot: str = "sim") -> str:
    """The swarm of these runs: ``dovrat_swarm`` at ``speed`` m/s in its mission."""
    swarm = {"plugin": "dovrat_swarm", "activate_on": ["MISSION"], "params": {"forward_speed": speed}}
    return swarm_config("d", swarm, bus="udpm://239.255.76.99:7699?ttl=0", bma="swarm", autopilot=autopilot)


# The script's draws matter too: lossy broadcasts, a freeze and seeded packet losses.
SCRIPT = """
mission_time = 6.0
[broadcast]
reception = 0.8
[[direction]]
at = 1.0
azimuth = 45.0
[[fault]]
kind = "freeze"
agent = "d-03"
at = 2.0
duration = 1.5
[[fault]]
kind = "packet_loss"
topics = ["TELEMETRY"]
loss = 0.3
delay = 0.2
agent = "*"
at = 0.0
duration = 3.0
"""


def message_hashes(log: Path) -> list[str]:
    """One hash per message, in order: its channel, time and bytes."""
    out = []
    ev = lcm.EventLog(str(log), "r")
    try:
        while (e := ev.read_next_event()) is not None:
            out.append(hashlib.sha256(b"%d|%s|" % (e.timestamp, e.channel.encode()) + e.data).hexdigest())
    finally:
        ev.close()
    return out


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("simtime")
    (d / "swarm.toml").write_text(config(2.0))
    (d / "changed.toml").write_text(config(2.5))
    (d / "mavlink.toml").write_text(config(2.0, "mavlink"))
    (d / "osc.toml").write_text(config(2.0) + '[osc]\nenabled = true\nserver = "http://127.0.0.1:9"\n')
    (d / "script.toml").write_text(SCRIPT)
    return d


def fly(files: Path, seed: int, name: str) -> Path:
    out = files / name
    outcome = run(
        Experiment(
            config_path=str(files / "swarm.toml"),
            agents=AGENTS,
            script=load_script(files / "script.toml"),
            output=str(out),
            force=True,
            speed=math.inf,
            seed=seed,
        )
    )
    assert outcome.code == 0, outcome.text()
    assert outcome.simulated_s is not None and outcome.simulated_s > 6.0
    return out


@pytest.fixture(scope="module")
def recorded(files: Path) -> Path:
    return fly(files, 1, "seed1.lcm")


def test_one_seed_gives_the_same_messages_and_another_seed_others(files: Path, recorded: Path) -> None:
    again = files / "seed1-again.lcm"
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    argv = ["--log-level", "WARNING", "run", str(files / "swarm.toml"), "--agents", str(AGENTS), "--headless"]
    argv += ["--script", str(files / "script.toml"), "-o", str(again), "--speed", "max", "--seed", "1"]
    proc = run_antalate(*argv, env=env, timeout=None)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    first = message_hashes(recorded)
    assert len(first) > 5000  # 20 agents' states, telemetry, commands and the faults' records
    assert message_hashes(again) == first
    assert recorded.read_bytes() == again.read_bytes()

    other = message_hashes(fly(files, 2, "seed2.lcm"))
    assert other != first
    assert first_divergence(recorded, files / "seed2.lcm") is not None


def test_replay_reproduces_a_recorded_run(recorded: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(recorded)]) == 0
    assert "replay matches the recording" in capsys.readouterr().out


def test_replay_reports_the_first_divergence_of_a_changed_parameter(
    files: Path, recorded: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["replay", str(recorded), "--config", str(files / "changed.toml")]) == 1
    out = capsys.readouterr().out
    assert "is not the file the run was recorded with" in out
    # The first message the parameter changes: a behavior's velocity command, 2.0 m/s forward.
    assert "VELOCITY_CMD" in out and "vx: 2.0 recorded, 2.5 replayed" in out, out


def test_replay_reports_the_first_divergence_of_an_edited_log(
    files: Path, recorded: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edited = files / "edited.lcm"
    events = []
    ev = lcm.EventLog(str(recorded), "r")
    while (e := ev.read_next_event()) is not None:
        events.append((e.timestamp, e.channel, bytes(e.data)))
    ev.close()
    k = next(i for i, (_, ch, _) in enumerate(events) if i > 1000 and ch.endswith("TELEMETRY"))
    msg = telemetry_t.decode(events[k][2])
    msg.battery = 12.5  # an edit of the log's message k (no swarm key: no MAC to break)
    events[k] = (events[k][0], events[k][1], msg.encode())
    out = lcm.EventLog(str(edited), "w", overwrite=True)
    for utime, channel, data in events:
        out.write_event(utime, channel, data)
    out.close()
    shutil.copy(record_path(recorded), record_path(edited))

    assert main(["replay", str(edited)]) == 1
    text = capsys.readouterr().out
    assert f"diverged at message {k} ({events[k][1]}, t = " in text, text
    assert "telemetry_t battery: 12.5 recorded" in text, text


def test_replay_needs_the_run_record(files: Path, recorded: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bare = files / "bare.lcm"
    shutil.copy(recorded, bare)
    assert main(["replay", str(bare)]) == 2
    err = capsys.readouterr().err
    assert "bare.lcm.run.json" in err and "--speed" in err and "\n" not in err.strip()
    record = json.loads(record_path(recorded).read_text())
    assert record["agents"] == AGENTS and record["script"]["seed"] == 1


@pytest.mark.parametrize(
    ("config", "argv", "words"),
    [
        ("swarm.toml", ["--speed", "max"], "--speed needs --headless"),
        (
            "mavlink.toml",
            ["--agents", "1", "--speed", "max", "--headless"],
            "hlc.autopilot: 'sim' with --speed",
        ),
        ("osc.toml", ["--speed", "max", "--headless"], "osc.enabled: false with --speed"),
    ],
)
def test_simulated_time_refuses_what_it_cannot_run_in_one_line(
    files: Path, config: str, argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", str(files / config), "--agents", "3", "-o", str(files / "x.lcm"), *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not (files / "x.lcm").exists()


@pytest.mark.parametrize("speed", ["0", "-3", "fast", "inf", "nan"])
def test_a_bad_speed_is_refused(files: Path, speed: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["run", str(files / "swarm.toml"), "--headless", "--speed", speed])
    assert "'max' or a number > 0" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the clock itself
def test_the_clock_jumps_to_each_timer_and_runs_what_it_sends_before_moving_on() -> None:
    clock = SimClock()
    ex = Executor(sim=clock)
    seen: list[tuple[str, float]] = []

    def slow() -> None:
        seen.append(("slow", clock.elapsed))
        ex.call_soon(lambda: seen.append(("after slow", clock.elapsed)))

    ex.create_timer(0.5, lambda: seen.append(("fast", clock.elapsed)), first_delay=0.25)
    ex.create_timer(1.0, slow)
    ex.call_later(100.0, lambda: ex.run_sync(ex.stop))
    started = time.monotonic()
    ex.start()
    while ex.loop.is_running() or clock.elapsed < 100.0:
        time.sleep(0.01)
        assert time.monotonic() - started < 60, "100 simulated seconds never passed"
    assert seen[:6] == [
        ("fast", 0.25),
        ("fast", 0.75),
        ("slow", 1.0),
        ("after slow", 1.0),  # what a timer sends runs at its time, before time moves on
        ("fast", 1.25),
        ("fast", 1.75),
    ]
    assert sum(1 for s in seen if s[0] == "fast") == 200
    assert ex.clock() == clock.t and ex.wallclock() == SIM_EPOCH + clock.t - SIM_START


def test_a_held_clock_stands_still_and_a_speed_is_an_upper_bound() -> None:
    clock = SimClock(speed=20.0, held=True)
    ex = Executor(sim=clock)
    ticks: list[float] = []
    ex.create_timer(0.1, lambda: ticks.append(clock.elapsed))
    ex.start()
    try:
        time.sleep(0.2)
        assert ticks == [] and clock.elapsed == 0.0  # held: nothing due later has run
        started = time.monotonic()
        ex.call_soon(clock.release)
        while len(ticks) < 10:
            time.sleep(0.005)
        # 1 simulated second at 20x real time takes at least 50 ms of real time.
        assert time.monotonic() - started >= 0.045
        # Each at its time, or up to 1 ms after (the executor's timer slots).
        assert ticks[:10] == pytest.approx([0.1 * (i + 1) for i in range(10)], abs=1.5e-3)
    finally:
        ex.stop()
