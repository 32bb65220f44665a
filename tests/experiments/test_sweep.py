"""``antalate sweep``: parameters x seeds, each point one real ``antalate run`` child process (MC, HLC,
BMA with ``dovrat_swarm`` on ``memq://`` in its own process, a scripted operator, a recorder), one
table of the swarm metrics (docs/experiments.md, "Sweeps").

Lean on purpose: 2 agents, a 2 s mission, a 2 m take-off; the sweep of 20 runs goes 2 at a time.
"""

from __future__ import annotations

import csv
import io
import json
import time
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.core.config import read_toml_file
from antalate_lcm.runtime.sweep import (
    METRICS,
    Progress,
    check_slots,
    load_sweep,
    metrics_row,
    prepare_output,
    run_sweep,
    slot_buses,
)
from antalate_lcm.runtime.sweep_spec import dumps_toml, expand, parse_spec
from tests import REPO
from tests.harness.agents import swarm_config
from tests.harness.cases import cases
from tests.harness.process import antalate_argv

SWARM = {"plugin": "dovrat_swarm", "params": {"forward_speed": 2.0, "sharp_turn_rate": 40.0}}
SIM = {"climb_rate": 5.0, "descent_rate": 4.0, "rtl_speed": 10.0}
CONFIG = swarm_config("d", SWARM, bma="swarm", takeoff=2.0, sim=SIM)
UDPM_CONFIG = swarm_config(
    "d", SWARM, bus="udpm://239.255.76.67:7667?ttl=0", bma="swarm", takeoff=2.0, sim=SIM
)

#: Each agent's position reads 3 m north with probability 1/2, drawn from the seed: the seeds
#: give different runs.
SCRIPT = """
mission_time = 2.0
[[fault]]
kind = "sensor"
sensor = "position"
mode = "bias"
offset = [3.0, 0.0]
agent = "*"
at = 0.5
probability = 0.5
"""

SPEC = """
config = "swarm.toml"
script = "script.toml"
agents = 2
seeds = 5
[parameters]
"behavior.dovrat_swarm.forward_speed" = [1.0, 2.0]
"behavior.dovrat_swarm.sharp_turn_rate" = [20.0, 40.0]
"""


def _files(folder: Path, spec: str = SPEC, config: str = CONFIG, script: str = SCRIPT) -> Path:
    (folder / "swarm.toml").write_text(config)
    (folder / "script.toml").write_text(script)
    path = folder / "sweep.toml"
    path.write_text(spec)
    return path


def test_a_sweep_on_simulated_time_repeats_itself_byte_for_byte(tmp_path: Path) -> None:
    """``speed = "max"``: each run on simulated time (antalate run --speed), so a point and a seed are
    one log; two sweeps of the same spec write the same bytes, and a second seed another."""
    from antalate_lcm.cli import main

    spec = SPEC.replace("seeds = 5", 'seeds = [3, 4]\nspeed = "max"').split("[parameters]")[0]
    path = _files(tmp_path, spec + '[parameters]\n"behavior.dovrat_swarm.forward_speed" = [1.5]\n')
    logs = []
    for name in ("a", "b"):
        assert main(["sweep", str(path), "-o", str(tmp_path / name), "--jobs", "2"]) == 0
        table = json.loads((tmp_path / name / "results.json").read_text())
        assert [r["status"] for r in table] == ["ok", "ok"], table
        outcome = json.loads((tmp_path / name / table[0]["log"]).with_name("outcome.json").read_text())
        assert outcome["simulated_s"], outcome  # flown on simulated time
        logs.append([(tmp_path / name / r["log"]).read_bytes() for r in table])
    assert logs[0][0] == logs[1][0] and logs[0][1] == logs[1][1]
    assert logs[0][0] != logs[0][1]


def test_a_sweep_of_dovrat_swarm_over_two_parameters_and_five_seeds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from antalate_lcm.cli import main

    spec = _files(tmp_path, SPEC.replace("seeds = 5", 'seeds = 5\nspeed = "max"'))  # simulated time: quick
    out = tmp_path / "results"
    started = time.monotonic()
    assert main(["sweep", str(spec), "-o", str(out), "--jobs", "2"]) == 0
    took = time.monotonic() - started
    captured = capsys.readouterr()
    assert "20 of 20 runs, 0 failed" in captured.out
    progress = [
        line for line in captured.err.splitlines() if line.startswith("sweep: ") and " ok in " in line
    ]
    assert len(progress) == 20, captured.err  # not a terminal: one plain line per run
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    table = json.loads((out / "results.json").read_text())
    assert len(rows) == len(table) == 20
    speed, turn = "behavior.dovrat_swarm.forward_speed", "behavior.dovrat_swarm.sharp_turn_rate"
    assert list(rows[0])[:4] == ["run", speed, turn, "seed"] and set(METRICS) <= set(rows[0])
    assert sorted((r[speed], r[turn], r["seed"]) for r in table) == sorted(
        (s, t, seed) for s in (1.0, 2.0) for t in (20.0, 40.0) for seed in range(5)
    )
    for row in table:
        assert row["status"] == "ok" and row["reason"] == "", row
        assert row["agents"] == 2 and row["mission_s"] > 1.5 and row["messages"] > 100
        assert 0.0 <= row["polarisation_mean"] <= 1.0 and row["min_separation"] > 0.0
        log = out / row["log"]
        assert log.is_file() and log.parent.name == f"{row['run']:04d}"
        # each run flew exactly its point: the config and script it was given are beside its log
        config = (log.parent / "config.toml").read_text()
        assert f'"forward_speed" = {row[speed]}' in config and f'"sharp_turn_rate" = {row[turn]}' in config
        assert f'"seed" = {row["seed"]}' in (log.parent / "script.toml").read_text()
    # the seed draws which agents' sensors lie: the five seeds of one point do not all agree
    hits = {r["seed"]: r["faults"] for r in table if r[speed] == 1.0 and r[turn] == 20.0}
    assert len(set(hits.values())) > 1, hits
    # the CSV holds what the JSON holds
    assert [r["run"] for r in rows] == [str(r["run"]) for r in table]
    assert float(rows[3]["radius_max"]) == pytest.approx(table[3]["radius_max"], rel=1e-5)
    print(f"sweep of 20 runs: {took:.1f} s")
    # the plotting example of docs/experiments.md draws it
    import subprocess
    import sys

    plot = REPO / "examples" / "sweep" / "plot_sweep.py"
    png = tmp_path / "sweep.png"
    argv = [sys.executable, str(plot), str(out / "results.csv"), "--x", speed, "--lines", turn]
    done = subprocess.run(
        [*argv, "--metric", "radius_max", "-o", str(png)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"{png}: radius_max of 20 runs" and png.stat().st_size > 10_000


def test_a_failed_or_timed_out_run_is_a_failed_row_and_the_sweep_goes_on(tmp_path: Path) -> None:
    """Run 0's operator gives up at once (the script's timeout: 0.2 s beyond a 1 s mission); run 1
    (a 60 s mission) outlives the sweep's own timeout (4 s) and is stopped."""
    spec = _files(
        tmp_path,
        'config = "swarm.toml"\nscript = "script.toml"\nagents = 2\nseeds = [7]\ntimeout = 4.0\n'
        '[parameters]\n"script.mission_time" = [1.0, 60.0]\n',
        script="mission_time = 2.0\ntimeout = 0.2\n",
    )
    sweep = load_sweep(spec)
    out = tmp_path / "r"
    prepare_output(out, force=False)
    stream = io.StringIO()
    result = run_sweep(sweep, out, jobs=2, progress=Progress(len(sweep.points), stream))
    rows = json.loads((out / "results.json").read_text())
    assert [(r["run"], r["status"]) for r in rows] == [(0, "failed"), (1, "failed")]
    assert result.failed == 2 and not result.interrupted
    assert rows[0]["reason"].startswith("FAILED: ") and "timed out after 1.2 s" in rows[0]["reason"], rows[0]
    assert rows[1]["reason"] == "timed out after 4 s (the sweep's timeout)"
    assert rows[1]["log"] == "runs/0001/flight.lcm"  # stopped in order: its log is whole
    lines = stream.getvalue().splitlines()
    assert "run 1 (mission_time=60.0 seed=7) failed: timed out after 4 s (the sweep's timeout)" in lines[-1]
    with pytest.raises(AntalateError, match=r"holds a sweep's results: pass --force"):
        prepare_output(out, force=False)


def test_an_interrupted_sweep_keeps_its_rows(tmp_path: Path) -> None:
    spec = _files(
        tmp_path,
        'config = "swarm.toml"\nagents = 2\nseeds = [1, 2, 3]\n[parameters]\n"script.mission_time" = [30.0]\n',
    )
    sweep = load_sweep(spec)
    out = tmp_path / "r"
    prepare_output(out, force=False)
    t0 = time.monotonic()
    result = run_sweep(
        sweep, out, jobs=2, progress=Progress(3, io.StringIO()), stop=lambda: time.monotonic() - t0 > 2.0
    )
    assert result.interrupted
    rows = json.loads((out / "results.json").read_text())
    # the two runs in flight were stopped (they landed and wrote their outcome); the third never started
    assert [(r["run"], r["status"], r["reason"]) for r in rows] == [
        (0, "interrupted", "interrupted"),
        (1, "interrupted", "interrupted"),
    ]
    assert (out / "results.csv").read_text().count("\n") == 3
    assert not (out / "runs" / "0002").exists()


def test_ctrl_c_stops_the_sweep_with_its_rows_written(tmp_path: Path) -> None:
    """SIGINT to ``antalate sweep`` (as Ctrl-C on its terminal): the runs in flight stop in order and
    are rows, the exit status is 130."""
    import signal
    import subprocess

    spec = _files(
        tmp_path,
        'config = "swarm.toml"\nagents = 2\nseeds = [1, 2, 3]\n[parameters]\n"script.mission_time" = [30.0]\n',
    )
    out = tmp_path / "r"
    argv = antalate_argv("sweep", str(spec), "-o", str(out), "-j", "1")
    sweep = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (out / "runs" / "0000" / "output.log").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)
        sweep.send_signal(signal.SIGINT)
        stdout, stderr = sweep.communicate(timeout=60)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert sweep.returncode == 130, stdout + stderr
    assert "1 of 3 runs, 1 failed (interrupted: the rows so far are written)" in stdout
    rows = json.loads((out / "results.json").read_text())
    assert [(r["run"], r["status"]) for r in rows] == [(0, "interrupted")]


@pytest.mark.parametrize(("spec", "key", "what"), cases("experiments/bad_specs.toml"))
def test_a_bad_spec_is_one_line_naming_the_key(tmp_path: Path, spec: str, key: str, what: str) -> None:
    path = _files(tmp_path, spec)
    with pytest.raises(ConfigError) as info:
        load_sweep(path)
    assert info.value.key == key and what in str(info.value), str(info.value)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_a_combination_refused_names_the_run(tmp_path: Path) -> None:
    """Each value alone is fine; together the direction falls after the end of the mission."""
    path = _files(
        tmp_path,
        'config = "swarm.toml"\nscript = "script.toml"\n[parameters]\n'
        '"script.mission_time" = [2.0, 10.0]\n"script.direction.0.at" = [1.0, 5.0]\n',
        script="mission_time = 8.0\n[[direction]]\nat = 1.0\nazimuth = 90.0\n",
    )
    with pytest.raises(
        ConfigError, match=r"parameters: the run mission_time=2\.0 at=5\.0 seed=0 is refused: .*"
    ):
        load_sweep(path)


def test_the_cli_prints_one_line_for_a_bad_spec(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from antalate_lcm.cli import main

    path = _files(tmp_path, 'config = "swarm.toml"\nseeds = [1, 1]\n')
    assert main(["sweep", str(path), "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: seeds: each seed once" in err
    assert not (tmp_path / "r").exists()


def test_expansion_order_and_the_documents_of_a_run(tmp_path: Path) -> None:
    spec = parse_spec(
        {"config": "c", "seeds": [5, 6], "parameters": {"script.a": [1, 2], "config.b.c": ["x"]}}, "s"
    )
    seeds, points = expand(spec)
    assert seeds == (5, 6)
    assert [(dict(p.values), p.seed) for p in points] == [
        ({"script.a": 1, "config.b.c": "x"}, 5),
        ({"script.a": 1, "config.b.c": "x"}, 6),
        ({"script.a": 2, "config.b.c": "x"}, 5),
        ({"script.a": 2, "config.b.c": "x"}, 6),
    ]
    sweep = load_sweep(
        _files(
            tmp_path,
            'config = "swarm.toml"\n[parameters]\n"config.hlc.autopilot_params.tau" = [0.25]\n'
            '"behavior.dovrat_swarm.turn_direction" = [-1]\n"script.broadcast.reception" = [0.5]\n',
        )
    )
    config, script = sweep.documents(sweep.points[0])
    assert config["hlc"]["autopilot_params"]["tau"] == 0.25
    assert config["bma"][0]["behaviors"][0]["params"]["turn_direction"] == -1
    assert script == {"mission_time": 30.0, "broadcast": {"reception": 0.5}, "seed": 0}
    assert sweep.run_timeout(sweep.points[0]) == 30.0 + 180.0 + 60.0  # its script's mission and timeout
    longer = load_sweep(
        _files(tmp_path, 'config = "swarm.toml"\n[parameters]\n"script.mission_time" = [5.0, 500.0]\n')
    )
    assert [longer.run_timeout(p) for p in longer.points] == [245.0, 740.0]
    assert sweep.config_doc["hlc"]["autopilot_params"] == {
        "climb_rate": 5.0,
        "descent_rate": 4.0,
        "rtl_speed": 10.0,
    }
    # what a run's file holds reads back as the same document
    written = tmp_path / "run.toml"
    written.write_text(dumps_toml(config))
    assert read_toml_file(written) == config
    with pytest.raises(AntalateError, match="cannot write"):
        dumps_toml({"a": float("nan")})


def test_parallel_slots_get_their_own_udpm_ports(tmp_path: Path) -> None:
    config: dict[str, Any] = {"buses": {"lan": "udpm://239.255.76.67:7667?ttl=0", "mem": "memq://"}}
    slot_buses(config, 0, 4)
    assert config["buses"]["lan"] == "udpm://239.255.76.67:7667?ttl=0"
    slot_buses(config, 2, 4)
    assert config["buses"] == {"lan": "udpm://239.255.76.67:7867?ttl=0", "mem": "memq://"}
    with pytest.raises(AntalateError, match=r"buses\.w = 'zenoh://.*use --jobs 1"):
        slot_buses({"buses": {"w": "zenoh://tcp/127.0.0.1:7447"}}, 0, 2)
    udpm = CONFIG.replace(
        'lan = "memq://"', 'lan = "udpm://239.255.76.67:7667?ttl=0"\nb = "udpm://239.255.76.68:7767?ttl=0"'
    )
    sweep = load_sweep(_files(tmp_path, 'config = "swarm.toml"\n', config=udpm))
    check_slots(sweep, 1)
    with pytest.raises(AntalateError, match=r"parallel slot 1 would share port 7767 with slot 0's bus 'b'"):
        check_slots(sweep, 2)


@pytest.mark.netns
def test_parallel_runs_on_udpm_never_hear_each_other(netns, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Two runs at once on one multicast group (a namespace): each slot on its own port, each log
    holds its own run's agents and faults only."""

    from tests.harness.process import child_env

    spec = _files(
        tmp_path,
        'config = "swarm.toml"\nscript = "script.toml"\nagents = 2\nseeds = [1, 2]\n',
        config=UDPM_CONFIG + "[security]\ninsecure = true\n",
        script='mission_time = 2.0\n[[fault]]\nkind = "freeze"\nagent = "d-02"\nat = 0.5\nduration = 1.0\n',
    )
    out = tmp_path / "r"
    argv = antalate_argv("sweep", str(spec), "-o", str(out), "-j", "2")
    done = netns.run(argv, timeout=180, cwd=tmp_path, env=child_env())
    assert done.returncode == 0, done.stdout + done.stderr
    ports = []
    for run in ("0000", "0001"):
        outcome = json.loads((out / "runs" / run / "outcome.json").read_text())
        analysis = outcome["analysis"]
        assert analysis["agents"] == ["d-01", "d-02"]
        assert [(f["agent"], f["kind"], f["event"]) for f in analysis["faults"]] == [
            ("d-02", "freeze", "start"),
            ("d-02", "freeze", "end"),
        ]
        assert "OK: 2 agent(s)" in outcome["report"]
        ports.append(read_toml_file(out / "runs" / run / "config.toml")["buses"]["lan"])
    assert sorted(ports) == ["udpm://239.255.76.67:7667?ttl=0", "udpm://239.255.76.67:7767?ttl=0"]


def test_metrics_of_a_run_without_analysis_are_empty_and_the_bar_draws_in_place() -> None:
    assert metrics_row(None) == dict.fromkeys(METRICS)
    stream = io.StringIO()
    bar = Progress(4, stream, tty=True)
    bar.ended({"status": "failed", "run": 0, "reason": "x", "wall_s": 1.0}, "a=1 seed=0")
    bar.draw(running=2)
    bar.close()
    text = stream.getvalue()
    # a failed run is a line above the bar; an ok one only moves the bar
    assert text.startswith("\rsweep: 1/4 run 0 (a=1 seed=0) failed: x in 1.0 s\x1b[K\n")
    assert "\r[#######.......................] 1/4 runs, 2 running, 1 failed, 0:00" in text
    bar.ended({"status": "ok", "run": 1, "reason": "", "wall_s": 1.0}, "a=1 seed=1")
    assert stream.getvalue() == text
    assert "to go)" in text and text.endswith("\n")
