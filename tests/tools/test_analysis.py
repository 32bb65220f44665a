"""Log analysis (``antalate analyze`` / ``antalate plot``) on small logs with known trajectories.

Each log is written with ``lcm.EventLog`` exactly as ``lcm-logger`` would write it, so the reader is
tested against the real file format, and every expected number is computed by hand.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from antalate_lcm.apps.analysis import (
    Track,
    analyze,
    analyze_log,
    cohesion_at,
    default_plot_path,
    read_log,
)
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.base.geo import offset
from antalate_lcm.cli import main
from antalate_lcm.msgs import mc_state_t, velocity_cmd_t
from tests.harness.synthetic_logs import CORNERS, LAT0, LON0, LogWriter, square_swarm


# ----------------------------------------------------------------------------- reading
def test_reads_agents_states_and_folds_repeats(tmp_path: Path) -> None:
    record = read_log(square_swarm().write(tmp_path / "swarm.lcm"))
    assert sorted(record.agents) == sorted(CORNERS)
    a1 = record.agents["a-1"]
    assert [c.state for c in a1.mc_states] == ["STANDBY", "MISSION", "RTL"]
    assert a1.mc_states[1].t == pytest.approx(2.0)
    assert a1.mc_states[2].t == pytest.approx(18.05)
    assert [c.state for c in a1.hlc_states] == ["READY", "AIRBORNE"]
    assert len(a1.telemetry) == 201
    assert len(record.directions) == 1  # sent 17 times, one change
    d = record.directions[0]
    assert (d.active, d.azimuth, d.speed, d.target, d.sender) == (True, 80.0, 1.0, "", "operator")
    assert record.duration == pytest.approx(20.001)
    assert record.skipped == 0 and not record.truncated


def test_garbage_and_unknown_channels_are_counted_not_fatal(tmp_path: Path) -> None:
    w = square_swarm()
    w.add(5.0, "a-1/TELEMETRY", b"\x00garbage")
    w.add(5.0, "a-2/MC_STATE", b"")
    w.add(6.0, "SOMEONE_ELSES_CHANNEL", b"hello")
    w.add(6.0, "SOMEONE_ELSES_CHANNEL", b"hello")
    vel = velocity_cmd_t()
    w.add(7.0, "a-1/VELOCITY_CMD", vel.encode())
    record = read_log(w.write(tmp_path / "dirty.lcm"))
    assert record.undecodable == {"a-1/TELEMETRY": 1, "a-2/MC_STATE": 1}
    assert record.unknown == {"SOMEONE_ELSES_CHANNEL": 2}
    assert record.unused == {"VELOCITY_CMD": 1}
    assert record.skipped == 4
    result = analyze(record)
    assert result.drift and result.drift[0].error == pytest.approx(10.0, abs=1e-3)
    assert any("skipped 4 event(s)" in n for n in result.notes)


def test_a_damaged_tail_keeps_what_precedes_it(tmp_path: Path) -> None:
    path = square_swarm().write(tmp_path / "swarm.lcm")
    data = path.read_bytes()
    damaged = tmp_path / "damaged.lcm"
    damaged.write_bytes(data[: len(data) // 2] + b"\x00" * 64 + data[len(data) // 2 :])
    record = read_log(damaged)
    assert record.agents and 0 < record.events < read_log(path).events
    assert "truncated or damaged" in record.truncated
    assert any("truncated or damaged" in note for note in analyze(record, azimuth=0.0).notes)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file"),
        (b"", "empty file"),
        (b"this is a text file, not a log\n", "not an LCM log file"),
        (b"\xed\xa1", "not an LCM log file"),
    ],
)
def test_bad_files_are_one_line_errors(tmp_path: Path, content: bytes | None, message: str) -> None:
    path = tmp_path / "bad.lcm"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(AntalateError, match=message) as info:
        analyze_log(path)
    assert "\n" not in str(info.value)


def test_directory_and_log_without_telemetry(tmp_path: Path) -> None:
    with pytest.raises(AntalateError, match="is a directory"):
        read_log(tmp_path)
    w = LogWriter()
    w.add(0.0, "SOMEONE_ELSES_CHANNEL", b"x")
    with pytest.raises(AntalateError, match="no telemetry in this log"):
        analyze_log(w.write(tmp_path / "empty.lcm"))


# ----------------------------------------------------------------------------- metrics
def test_rigid_swarm_cohesion_and_drift_by_hand(tmp_path: Path) -> None:
    result = analyze(read_log(square_swarm().write(tmp_path / "swarm.lcm")))
    # the window: the last agent (a-4) entered MISSION at 3 s, the first (a-1) left at 18.05 s
    assert result.window is not None
    assert result.window.start == pytest.approx(3.0)
    assert result.window.end == pytest.approx(18.05)
    # corners of a 20 m square: every agent is 10*sqrt(2) from the centroid, all the time
    r = 10 * math.sqrt(2)
    assert result.start_radius == pytest.approx(r, abs=1e-3)
    assert result.peak_radius == pytest.approx(r, abs=1e-3)
    assert result.cohesion_ratio == pytest.approx(1.0, abs=1e-4)
    assert result.average_mean == pytest.approx(r, abs=1e-3)
    # moving east (90 deg) at 1 m/s while 80 deg was commanded (from 3 s: the window's start)
    (d,) = result.drift
    assert (d.start, d.end) == pytest.approx((3.0, 18.05))
    assert d.heading == pytest.approx(90.0, abs=1e-3)
    assert d.error == pytest.approx(10.0, abs=1e-3)
    assert d.distance == pytest.approx(15.05, abs=1e-3)
    assert d.speed == pytest.approx(1.0, abs=1e-4)
    assert (d.azimuth, d.commanded_speed, d.agents, d.source) == (80.0, 1.0, 4, "log")


def test_expanding_swarm_ratio_by_hand(tmp_path: Path) -> None:
    # each agent flies straight away from the centre at 0.5 m/s: radius 10*sqrt(2) + 0.5 t
    def away(name: str, t: float) -> tuple[float, float]:
        n, e = CORNERS[name]
        k = 1 + 0.5 * t / (10 * math.sqrt(2))
        return n * k, e * k

    result = analyze(read_log(square_swarm(away).write(tmp_path / "out.lcm")), azimuth=0.0)
    r0 = 10 * math.sqrt(2)
    assert result.start_radius == pytest.approx(r0 + 1.5, abs=1e-3)  # at 3 s
    assert result.peak_radius == pytest.approx(r0 + 9.0, abs=1e-3)  # the last bin inside, 18 s
    assert result.cohesion_ratio == pytest.approx((r0 + 9.0) / (r0 + 1.5), abs=1e-4)
    (d,) = result.drift
    assert d.heading is None and d.error is None  # the centroid never moved
    assert d.distance == pytest.approx(0.0, abs=1e-3)
    assert d.source == "option"


def test_direction_changes_make_spans_and_azimuth_option_wins(tmp_path: Path) -> None:
    w = square_swarm(azimuth=None)
    w.direction(2.5, 80.0)
    w.direction(8.0, 100.0)
    w.direction(12.0, 0.0, active=False)  # stop: no drift measured from here
    w.direction(13.0, 30.0, target="a-2", channel="a-2/DIRECTION_CMD")  # one agent's: not the swarm's
    path = w.write(tmp_path / "turns.lcm")
    result = analyze_log(path)
    assert [(round(d.start, 3), round(d.end, 3), d.azimuth) for d in result.drift] == [
        (3.0, 8.0, 80.0),
        (8.0, 12.0, 100.0),
    ]
    assert [round(d.error, 3) for d in result.drift if d.error is not None] == [10.0, -10.0]
    forced = analyze_log(path, azimuth=350.0)
    (d,) = forced.drift
    assert d.error == pytest.approx(100.0, abs=1e-3)  # 90 is 100 deg clockwise of 350


def test_a_silent_agent_leaves_the_cohesion_and_the_drift(tmp_path: Path) -> None:
    w = LogWriter()
    for name, (n, e) in CORNERS.items():
        w.mc(0.0, name, mc_state_t.MISSION)
        stop = 10.0 if name == "a-4" else 20.0  # a-4 is cut off at 10 s
        for k in range(int(stop * 10) + 1):
            w.telemetry(k / 10, name, n + 0.5 * k / 10, e)
    result = analyze(read_log(w.write(tmp_path / "cut.lcm")), azimuth=0.0)
    by_t = {round(c.t): c for c in result.cohesion}
    assert by_t[5].agents == 4 and by_t[11].agents == 4  # still within max_age (2 s)
    assert by_t[13].agents == 3 and by_t[19].agents == 3
    # three corners (10,10), (10,-10), (-10,-10): centroid (10/3, -10/3) + the drift north;
    # the radius is the distance to (10,10) or (-10,-10): hypot(20/3, 40/3)
    c = by_t[15]
    assert c.centroid_north - 0.5 * 15 == pytest.approx(10 / 3, abs=1e-3)
    assert c.centroid_east == pytest.approx(-10 / 3, abs=1e-3)
    assert c.max_distance == pytest.approx(math.hypot(20 / 3, 40 / 3), abs=1e-3)
    (d,) = result.drift  # over the three heard at both ends: exactly north at 0.5 m/s
    assert (
        d.agents == 3
        and d.heading == pytest.approx(0.0, abs=1e-3)
        and d.speed == pytest.approx(0.5, abs=1e-3)
    )


def test_track_interpolation_and_staleness() -> None:
    tr = Track([0.0, 1.0, 5.0], [0.0, 10.0, 10.0], [0.0, 0.0, 40.0], [0.0, 0.0, 0.0])
    assert tr.position_at(-0.1, 2.0) is None
    assert tr.position_at(0.25, 2.0) == pytest.approx((2.5, 0.0))
    assert tr.position_at(2.0, 2.0) == pytest.approx((10.0, 0.0))  # gap of 4 s: no interpolation
    assert tr.position_at(3.5, 2.0) is None  # last heard 2.5 s ago
    assert tr.position_at(6.0, 2.0) == pytest.approx((10.0, 40.0))
    assert tr.position_at(7.5, 2.0) is None
    sample = cohesion_at({"x": tr, "y": Track([0.0], [0.0], [0.0], [0.0])}, 0.5, 2.0)
    assert sample is not None
    assert sample.agents == 2
    assert (sample.centroid_north, sample.max_distance) == pytest.approx((2.5, 2.5))


# ----------------------------------------------------------------------------- the commands
def test_cli_analyze_text_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = square_swarm().write(tmp_path / "swarm.lcm")
    assert main(["analyze", str(path)]) == 0
    text = capsys.readouterr().out
    assert "a-1: STANDBY@0.0 -> MISSION@2.0 -> RTL@18.1" in text
    assert "= 1.00 x the starting radius" in text
    assert "error +10.0 deg" in text
    assert main(["analyze", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["drift"][0]["error"] == pytest.approx(10.0, abs=1e-3)
    assert data["cohesion_ratio"] == pytest.approx(1.0, abs=1e-4)
    assert data["window"]["start"] == pytest.approx(3.0)
    assert len(data["cohesion"]) == 21


def test_cli_plot_writes_a_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = square_swarm().write(tmp_path / "swarm.lcm")
    out = tmp_path / "figure.png"
    assert main(["plot", str(path), "-o", str(out), "-q"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out.stat().st_size > 20_000
    assert f"wrote {out}" in capsys.readouterr().out
    assert main(["plot", str(path), "-q"]) == 0
    assert default_plot_path(path) == tmp_path / "swarm.png" and (tmp_path / "swarm.png").exists()
    assert default_plot_path("lcmlog-2026-11-22.00").name == "lcmlog-2026-11-22.00.png"


def test_cli_bad_file_is_one_line_and_status_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "notes.txt"
    bad.write_text("not a log")
    assert main(["plot", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an LCM log file" in err
    assert main(["analyze", str(tmp_path / "missing.lcm")]) == 2
    assert "no such file" in capsys.readouterr().err


# ----------------------------------------------------------------------------- recording and replay
@pytest.mark.netns
def test_antalate_log_records_and_lcm_logplayer_replays(netns, probe, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The stock-tools recipe of docs/logging.md, end to end on real multicast in a namespace."""
    import subprocess

    from antalate_lcm.runtime.cli import native_lcm_tool
    from tests.conftest import MCAST_URL
    from tests.harness.polling import wait_for
    from tests.harness.process import stop_process

    cfg = tmp_path / "operator.toml"
    cfg.write_text(f'[agent]\nname = "operator"\n[buses]\nlan = "{MCAST_URL}"\n')
    log = tmp_path / "mission.lcm"
    logger = netns.antalate("log", str(cfg), "-o", str(log), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert logger.stdout is not None and "logging bus 'lan'" in logger.stdout.readline()

    # lcm-logger subscribes right after exec, which a loaded machine makes later than the 0.5 s once
    # waited here (5 of 20 messages went unrecorded at load 7): an unrelated agent's state until one is on
    # disk (the logger flushes every 100 ms)
    def logging_now() -> bool:
        probe.publish("x-0/MC_STATE", "mc_state_t", header={"agent": "x-0"}, state=3)
        return log.exists() and log.stat().st_size > 0

    assert wait_for(logging_now, 20, interval=0.2)
    for k in range(20):
        probe.publish("x-1/MC_STATE", "mc_state_t", header={"agent": "x-1", "seq": k}, state=3)
        lat, lon = offset(LAT0, LON0, 0.0, float(k))
        probe.publish(
            "x-1/TELEMETRY",
            "telemetry_t",
            header={"agent": "x-1", "seq": k},
            lat=lat,
            lon=lon,
            in_air=True,
            mode="GUIDED",
        )
    probe.publish(
        "SWARM/DIRECTION_CMD",
        "direction_cmd_t",
        header={"agent": "operator"},
        active=True,
        azimuth=90.0,
        speed=1.0,
    )

    def logged() -> int:
        """The direction, published last, is on disk: lcm-logger writes through a buffer it flushes
        when a message comes 100 ms after the last flush, so the unrelated agent's state goes on."""
        import lcm

        probe.publish("x-0/MC_STATE", "mc_state_t", header={"agent": "x-0"}, state=3)
        return sum(e.channel == "SWARM/DIRECTION_CMD" for e in lcm.EventLog(str(log), "r"))

    assert wait_for(logged, 20, interval=0.2)
    assert stop_process(logger) in (0, -15)  # SIGTERM reaches lcm-logger itself: the file is complete
    record = read_log(log)
    assert len(record.agents["x-1"].telemetry) == 20
    assert [c.state for c in record.agents["x-1"].mc_states] == ["MISSION"]
    assert record.directions[0].azimuth == 90.0
    # refusing to overwrite without --force: a one-line error before anything starts
    again = netns.run([sys.executable, "-m", "antalate_lcm.cli", "log", str(cfg), "-o", str(log)])
    assert again.returncode == 2 and "exists" in again.stderr
    # replay: lcm-logplayer publishes the log on the bus again, where any node hears it
    mark = probe.mark()
    player = netns.run([native_lcm_tool("lcm-logplayer"), "--speed=10", f"--lcm-url={MCAST_URL}", str(log)])
    assert player.returncode == 0, player.stderr
    replayed = probe.history("x-1/TELEMETRY", "telemetry_t", since=mark)
    assert len(replayed) == 20 and replayed[-1]["lat"] == pytest.approx(offset(LAT0, LON0, 0.0, 19.0)[0])


@pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")
def test_file_provider_replays_a_log_into_a_bus(tmp_path: Path) -> None:
    """LCM's ``file://`` provider as a bus URL: any antalate node (the console too) reads a log as if live."""
    import time

    from antalate_lcm.core.bus import Buses

    path = square_swarm().write(tmp_path / "swarm.lcm")
    got: list[str] = []
    bus = Buses({"lan": f"file://{path}?speed=0"})
    try:
        bus.subscribe("lan", "a-.*/MC_STATE", mc_state_t, lambda ch, _m: got.append(ch), regex=True)
        bus.open()
        deadline = time.monotonic() + 10
        while len(got) < 4 * 102 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        bus.close()
    assert len(got) == 4 * 102  # per agent: STANDBY, MISSION and 100 republished states
