"""Swarm metrics for any algorithm (antalate_lcm/apps/analysis/swarm.py, geometry.py, phases.py) against
synthetic trajectories whose answers are worked out by hand in each test.

The logs are written with ``lcm.EventLog`` as ``lcm-logger`` writes them (tests/harness/synthetic_logs.py),
so the whole path -- reading, the local frame, sampling, the metrics -- is the one a user's log takes.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import pytest

from antalate_lcm.apps.analysis import Analysis, analyze_log
from antalate_lcm.apps.analysis.geometry import (
    closest_pair,
    components,
    nearest_neighbour_distances,
    polarisation,
    quantile,
)
from antalate_lcm.apps.analysis.swarm import sample_times
from antalate_lcm.cli import main
from antalate_lcm.msgs import mc_state_t
from tests import REPO
from tests.harness.synthetic_logs import CORNERS, LogWriter

R0 = 10 * math.sqrt(2)  # a corner's distance to the centre of the 20 m square


# ----------------------------------------------------------------------------- one instant
def test_closest_pair_nearest_neighbours_and_components() -> None:
    pts = {"a": (0.0, 0.0), "b": (0.0, 3.0), "c": (0.0, 10.0), "d": (20.0, 0.0)}
    assert closest_pair(pts) == pytest.approx((3.0, "a", "b"))
    assert closest_pair({"a": (0.0, 0.0)}) is None
    assert nearest_neighbour_distances(pts) == pytest.approx({"a": 3.0, "b": 3.0, "c": 7.0, "d": 20.0})
    assert nearest_neighbour_distances({"a": (1.0, 1.0)}) == {}
    # range 7: a-b-c chain (3 and 7 apart, inclusive), d alone; range 6.9: c drops off
    assert components(pts, 7.0) == [{"a", "b", "c"}, {"d"}]
    assert components(pts, 6.9) == [{"a", "b"}, {"c"}, {"d"}]
    assert components(pts, 25.0) == [{"a", "b", "c", "d"}]
    # ties: the pair whose names sort first
    tie = closest_pair({"z": (0.0, 0.0), "y": (0.0, 1.0), "x": (0.0, 2.0)})
    assert tie is not None and tie[1:] == ("x", "y")


def test_polarisation_known_values() -> None:
    assert polarisation([(1.0, 0.0), (3.0, 0.0), (0.5, 0.0)], 0.2) == pytest.approx(1.0)
    assert polarisation([(1.0, 0.0), (-1.0, 0.0)], 0.2) == pytest.approx(0.0)
    assert polarisation([(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)], 0.2) == pytest.approx(0.0)
    # two at right angles: |(1,1)/2| = sqrt(2)/2, whatever their speeds
    assert polarisation([(2.0, 0.0), (0.0, 5.0)], 0.2) == pytest.approx(math.sqrt(2) / 2)
    # the slow one (0.1 m/s, pointing the other way) has no heading and is left out
    assert polarisation([(1.0, 0.0), (1.0, 0.0), (-0.1, 0.0)], 0.2) == pytest.approx(1.0)
    assert polarisation([(1.0, 0.0), (0.0, 0.0)], 0.2) is None  # one moving agent: undefined


def test_quantile_and_sample_times() -> None:
    assert quantile([0.0, 10.0], 0.5) == 5.0
    assert quantile([1.0, 2.0, 3.0, 4.0, 5.0], 0.1) == pytest.approx(1.4)
    with pytest.raises(ValueError):
        quantile([1.0], 1.5)
    assert sample_times(0.0, 1.0, 0.5) == [0.0, 0.5, 1.0]
    assert sample_times(0.0, 1.2, 0.5) == [0.0, 0.5, 1.0, 1.2]
    with pytest.raises(ValueError):
        sample_times(0.0, 1.0, 0.0)


# ----------------------------------------------------------------------------- flights
def _flight(
    path: Path,
    position: Callable[[str, float], tuple[float, float, float, float]],
    *,
    until: float,
    states: list[tuple[float, int]] | None = None,
) -> Path:
    """Four agents at 10 Hz; ``position(name, t)`` -> (north, east, vn, ve); MC states for all."""
    w = LogWriter()
    for name in CORNERS:
        for t, state in states or []:
            w.mc(t, name, state)
        for k in range(int(round(until * 10)) + 1):
            n, e, vn, ve = position(name, k / 10)
            w.telemetry(k / 10, name, n, e, vn=vn, ve=ve)
    return w.write(path)


def _gathering(name: str, t: float) -> tuple[float, float, float, float]:
    """The corners of a 20 m square, scaled by k(t): 1 until 3 s; in MISSION (3..13 s) straight to
    the centre, k = 1 - 0.08 (t - 3) down to 0.2; on the way home (13..17 s) out to 1.5."""
    n0, e0 = CORNERS[name]
    if t <= 3.0:
        k, dk = 1.0, 0.0
    elif t <= 13.0:
        k, dk = 1.0 - 0.08 * (t - 3.0), -0.08
    elif t <= 17.0:
        k, dk = 0.2 + 1.3 * (t - 13.0) / 4.0, 1.3 / 4.0
    else:
        k, dk = 1.5, 0.0
    return n0 * k, e0 * k, n0 * dk, e0 * dk


GATHERING_STATES = [
    (0.0, mc_state_t.STANDBY),
    (1.0, mc_state_t.TAKEOFF),
    (3.0, mc_state_t.MISSION),
    (13.0, mc_state_t.RTL),
    (16.0, mc_state_t.LAND),
    (17.0, mc_state_t.STANDBY),
]


@pytest.fixture(scope="module")
def gathering(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Analysis]:
    path = _flight(
        tmp_path_factory.mktemp("gathering") / "gathering.lcm",
        _gathering,
        until=18.0,
        states=GATHERING_STATES,
    )
    return path, analyze_log(path, radius_below=5.0, radius_above=12.0, range_m=10.0)


def test_phases_keep_takeoff_mission_and_return_apart(gathering: tuple[Path, Analysis]) -> None:
    _, result = gathering
    assert [p.phase.name for p in result.phases] == ["takeoff", "mission", "return"]
    assert [t for p in result.phases for t in (p.phase.start, p.phase.end)] == pytest.approx(
        [1.0, 3.0, 3.0, 13.0, 13.0, 17.0]
    )
    mission, ret = result.phase("mission"), result.phase("return")
    assert mission is not None and ret is not None
    assert mission.samples == 101  # 3.0, 3.1, ..., 13.0
    # the way home spreads the agents to 1.5 x the start: none of it is in the mission's figures
    assert mission.radius is not None and mission.radius.max == pytest.approx(R0, abs=1e-3)
    assert ret.radius is not None and ret.radius.max == pytest.approx(1.5 * R0, abs=1e-3)
    assert ret.radius.max_t == pytest.approx(17.0)


def test_radius_and_mean_distance_start_end_min_max(gathering: tuple[Path, Analysis]) -> None:
    mission = gathering[1].phase("mission")
    assert mission is not None and mission.radius is not None and mission.mean_distance is not None
    r = mission.radius
    assert (r.start, r.end) == pytest.approx((R0, 0.2 * R0), abs=1e-3)
    assert r.min == pytest.approx(0.2 * R0, abs=1e-3) and r.min_t == pytest.approx(13.0)
    assert r.max == pytest.approx(R0, abs=1e-3) and r.max_t == pytest.approx(3.0, abs=0.05)
    # the mean of a linear fall sampled evenly: the middle value, k = 0.6
    assert r.mean == pytest.approx(0.6 * R0, abs=1e-3)
    m = mission.mean_distance  # symmetric swarm: every agent at the radius
    assert (m.start, m.end, m.min) == pytest.approx((R0, 0.2 * R0, 0.2 * R0), abs=1e-3)


def test_time_until_the_radius_falls_below_and_rises_above(gathering: tuple[Path, Analysis]) -> None:
    mission, ret = gathering[1].phase("mission"), gathering[1].phase("return")
    assert mission is not None and ret is not None
    # below 5 m: k < 5 / R0, i.e. (1 - 5/R0) / 0.08 = 8.0806 s after the start: the 8.1 s sample
    assert mission.radius_below is not None
    assert mission.radius_below.after == pytest.approx(8.1, abs=1e-6)
    assert mission.radius_below.t == pytest.approx(11.1, abs=1e-6)
    # above 12 m on the way home: k > 12/R0 from 0.2 at 0.325/s, 1.9955 s after 13 s: the 2.0 s sample
    assert ret.radius_above is not None and ret.radius_above.after == pytest.approx(2.0, abs=1e-6)
    # the mission starts at 14.1 m: above 12 m at once; the way home starts below 5 m: at once too
    assert mission.radius_above is not None and mission.radius_above.after == pytest.approx(0.0)
    assert ret.radius_below is not None and ret.radius_below.after == pytest.approx(0.0)
    # the climb stays at 14.1 m: never below
    takeoff = gathering[1].phase("takeoff")
    assert takeoff is not None and takeoff.radius_below is not None
    assert takeoff.radius_below.t is None and takeoff.radius_below.after is None


def test_min_separation_nearest_neighbours_connectivity(gathering: tuple[Path, Analysis]) -> None:
    mission = gathering[1].phase("mission")
    assert mission is not None
    sep = mission.min_separation
    assert sep is not None
    # the side of the square, 20 k: 4 m at the end, between two neighbouring corners
    assert sep.distance == pytest.approx(4.0, abs=1e-3) and sep.t == pytest.approx(13.0)
    assert {sep.a, sep.b} in ({"a-1", "a-2"}, {"a-2", "a-3"}, {"a-3", "a-4"}, {"a-1", "a-4"})
    nn = mission.nearest_neighbour
    assert nn is not None
    assert nn.count == 4 * 101
    assert (nn.min, nn.max) == pytest.approx((4.0, 20.0), abs=1e-3)
    assert (nn.median, nn.mean) == pytest.approx((12.0, 12.0), abs=1e-3)
    assert nn.p10 == pytest.approx(4.0 + 0.1 * 16.0, abs=1e-3)
    # connected at 10 m once the side is at most 10 m: k <= 0.5 from 9.25 s, i.e. the 38 samples 9.3..13.0
    c = mission.connectivity
    assert c is not None and c.range_m == 10.0
    assert c.connected_fraction == pytest.approx(38 / 101)
    assert c.first_split_t == pytest.approx(3.0)
    assert c.min_largest == 1 and c.min_largest_t == pytest.approx(3.0)
    # gathering: every agent heads for the centre, so the headings cancel out exactly
    assert mission.polarisation is not None and mission.polarisation.max == pytest.approx(0.0, abs=1e-6)


def test_the_python_api_returns_the_trajectories(gathering: tuple[Path, Analysis]) -> None:
    _, result = gathering
    assert sorted(result.tracks) == sorted(CORNERS)
    a1 = result.tracks["a-1"]
    assert len(a1.t) == 181
    i = a1.t.index(8.0)  # k = 0.6 in the mission
    assert (a1.north[i], a1.east[i]) == pytest.approx((6.0, 6.0), abs=1e-3)
    assert (a1.vn[i], a1.ve[i]) == pytest.approx((-0.8, -0.8), abs=1e-6)
    # the series over the whole log, every bin (1 s)
    assert [s.t for s in result.series] == [float(k) for k in range(19)]
    assert result.series[8].radius == pytest.approx(0.6 * R0, abs=1e-3)


def _crossing_flock(aligned: bool) -> Callable[[str, float], tuple[float, float, float, float]]:
    """a-1 flies east along north = 1, a-2 west along north = -1 (or east too, ``aligned``): they
    pass 2 m apart at 10 s. a-3 and a-4 fly east 50 m north of them, 5 m apart."""

    def position(name: str, t: float) -> tuple[float, float, float, float]:
        if name == "a-1":
            return 1.0, -10.0 + t, 0.0, 1.0
        if name == "a-2":
            return (-1.0, -10.0 + t, 0.0, 1.0) if aligned else (-1.0, 10.0 - t, 0.0, -1.0)
        return 50.0, (0.0 if name == "a-3" else 5.0) + t, 0.0, 1.0

    return position


def test_closest_approach_when_and_which_pair_and_polarisation(tmp_path: Path) -> None:
    # no MC states: the mission is the span in which every agent was in the air (0..20 s)
    result = analyze_log(_flight(tmp_path / "cross.lcm", _crossing_flock(False), until=20.0))
    mission = result.phase("mission")
    assert mission is not None and [p.phase.name for p in result.phases] == ["mission"]
    sep = mission.min_separation
    assert sep is not None
    assert sep.distance == pytest.approx(2.0, abs=1e-3) and sep.t == pytest.approx(10.0)
    assert (sep.a, sep.b) == ("a-1", "a-2")
    # three east, one west: |(0, 2/4)| = 0.5 all along
    pol = mission.polarisation
    assert pol is not None
    assert (pol.min, pol.max, pol.mean) == pytest.approx((0.5, 0.5, 0.5), abs=1e-6)
    aligned = analyze_log(_flight(tmp_path / "flock.lcm", _crossing_flock(True), until=20.0)).phase("mission")
    assert aligned is not None and aligned.polarisation is not None
    assert aligned.polarisation.min == pytest.approx(1.0, abs=1e-6)


def test_a_velocity_step_at_the_rtl_does_not_leak_into_the_mission(tmp_path: Path) -> None:
    """Four agents fly north together at 1 m/s; the RTL comes at 5.05 s, between two reports, and
    the next report (5.1 s) has each flying home at 4 m/s, every one its own way. The mission ends
    at 5.05 s: its last sample holds the report of 5.0 s (all north, polarisation 1), not a blend
    of the two reports (0.13 here; 0.26 for a real flock at 0.9996)."""

    def north_then_home(name: str, t: float) -> tuple[float, float, float, float]:
        n0, e0 = CORNERS[name]
        if t <= 5.0:
            return n0 + t, e0, 1.0, 0.0
        return n0 + 5.0, e0, -4.0 * n0 / R0, -4.0 * e0 / R0

    states = [(0.0, mc_state_t.STANDBY), (0.5, mc_state_t.MISSION), (5.05, mc_state_t.RTL)]
    result = analyze_log(_flight(tmp_path / "rtl.lcm", north_then_home, until=7.0, states=states))
    mission = result.phase("mission")
    assert mission is not None and mission.phase.end == pytest.approx(5.05)
    pol = mission.polarisation
    assert pol is not None and (pol.start, pol.end, pol.min) == pytest.approx((1.0, 1.0, 1.0), abs=1e-9)


def test_connectivity_first_split(tmp_path: Path) -> None:
    def chain(name: str, t: float) -> tuple[float, float, float, float]:
        i = int(name[-1]) - 1  # 0, 8, 16 m east, static; a-4 from 24 m, leaving at 0.3 m/s
        return (0.0, 8.0 * i, 0.0, 0.0) if i < 3 else (0.0, 24.0 + 0.3 * t, 0.0, 0.3)

    mission = analyze_log(_flight(tmp_path / "chain.lcm", chain, until=20.0), range_m=10.0).phase("mission")
    assert mission is not None and mission.connectivity is not None
    c = mission.connectivity
    # the gap 8 + 0.3 t exceeds 10 m after 6.67 s: the 6.7 s sample; 0.0..6.6 connected = 67 of 201
    assert c.first_split_t == pytest.approx(6.7)
    assert c.connected_fraction == pytest.approx(67 / 201)
    assert c.min_largest == 3 and c.min_largest_t == pytest.approx(6.7)
    assert mission.polarisation is None  # one moving agent: no order parameter


# ----------------------------------------------------------------------------- the commands
def test_cli_analyze_reports_every_metric_per_phase(
    gathering: tuple[Path, Analysis], capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = gathering
    assert main(["analyze", str(path), "--radius-below", "5", "--range", "10"]) == 0
    text = capsys.readouterr().out
    assert "phase takeoff: 1.0 .. 3.0 s" in text
    assert "phase mission: 3.0 .. 13.0 s" in text and "phase return: 13.0 .. 17.0 s" in text
    assert "radius first below 5 m: after 8.1 s (at 11.1 s)" in text
    assert "min separation     4.00 m at 13.0 s" in text
    assert "connected in 38 % of the samples" in text
    assert main(["analyze", str(path), "--json", "--radius-below", "5"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert "tracks" not in data
    mission = data["phases"][1]
    assert mission["phase"]["name"] == "mission"
    assert mission["radius_below"]["after"] == pytest.approx(8.1)
    assert mission["min_separation"]["distance"] == pytest.approx(4.0, abs=1e-3)
    assert mission["nearest_neighbour"]["count"] == 404
    assert len(data["series"]) == 19
    assert main(["analyze", str(path), "--json", "--tracks"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["tracks"]["a-1"]["north"]) == 181


def test_cli_rejects_nonsense_thresholds(
    gathering: tuple[Path, Analysis], capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = gathering
    for option, value in (("--radius-below", "-1"), ("--range", "nan"), ("--step", "0"), ("--goal", "inf")):
        cmd = "plot" if option == "--goal" else "analyze"
        with pytest.raises(SystemExit) as info:
            main([cmd, str(path), option, value])
        assert info.value.code == 2
        assert "expected a positive finite number" in capsys.readouterr().err


def test_plot_goal_lines_come_from_options_only(gathering: tuple[Path, Analysis], tmp_path: Path) -> None:
    from antalate_lcm.apps.analysis import read_log
    from antalate_lcm.apps.analysis.plot import figure

    path, result = gathering
    record = read_log(path)

    def labels(goals: tuple[float, ...]) -> list[str]:
        fig = figure(record, result, result.tracks, goals=goals)
        return fig.axes[2].get_legend_handles_labels()[1]

    default = labels(())
    assert not [label for label in default if "goal" in label or "starting radius" in label]
    assert {"takeoff", "mission", "return", "min separation"} <= set(default)
    assert [label for label in labels((5.0, 3.0)) if "goal" in label] == ["goal 5 m", "goal 3 m"]
    out = tmp_path / "g.png"
    assert main(["plot", str(path), "--goal", "5", "-q", "-o", str(out)]) == 0
    assert out.read_bytes()[:4] == b"\x89PNG"


def test_the_python_example_of_docs_logging_runs(
    gathering: tuple[Path, Analysis], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """docs/logging.md's Python example, as written, on a log called mission.lcm."""
    import shutil

    doc = (REPO / "docs" / "logging.md").read_text()
    block = doc.split("The same from Python, with the trajectories:", 1)[1].split("```python\n", 1)[1]
    code = block.split("```", 1)[0]
    shutil.copy(gathering[0], tmp_path / "mission.lcm")
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/logging.md", "exec"), {})  # noqa: S102 - the documented example itself
    assert (tmp_path / "mission.png").read_bytes()[:4] == b"\x89PNG"
