"""``antalate analyze`` on a swarm's safety (antalate_lcm/apps/analysis/safety.py, docs/safety.md): separation over
the whole log, near-misses, losses of separation, fence breaches, the HLCs' SAFETY reports and whether the
mission flew, on small logs whose answers are worked out by hand."""

from __future__ import annotations

from pathlib import Path

import pytest
import tomli_w

from antalate_lcm.apps.analysis import SafetyLimits, analyze_log, read_log
from antalate_lcm.apps.analysis.safety import event_kind
from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.cli import main
from antalate_lcm.msgs import mc_state_t
from tests.harness.synthetic_logs import LAT0, LON0, LogWriter

FENCE = Geofence(((-20.0, -20.0), (-20.0, 20.0), (20.0, 20.0), (20.0, -20.0)), 0.0, 30.0, 2.0)


def head_on(tmp_path: Path) -> Path:
    """a and b fly at each other along the east axis at 1 m/s each from 20 m apart for 8 s (closest:
    4 m at 8 s); c stands on the ground 0.5 m from a's start; d flies out of the fence east, 5 m/s;
    e lands below the floor on its spot. SAFETY reports and one other error in between."""
    w = LogWriter()
    for k in range(81):
        t = k / 10
        w.telemetry(t, "a", 0.0, -10.0 + t)
        w.telemetry(t, "b", 0.0, 10.0 - t)
        w.telemetry(t, "c", 0.5, -10.0, in_air=False, alt=0.0)
        w.telemetry(t, "d", 15.0, 5.0 * t + 2.25)  # out at t > 3.55 s (east > 20 m), 22.25 m out at 8 s
        w.telemetry(t, "e", -15.0, -15.0, alt=max(0.0, 5.0 - t), in_air=t < 5.0)
    for agent in "abcde":
        w.mc(0.0, agent, mc_state_t.MISSION)
        w.mc(8.0, agent, mc_state_t.STANDBY)
    w.telemetry(8.05, "a", 0.0, -2.0, in_air=False, alt=0.0)
    w.telemetry(8.05, "b", 0.0, 2.0, in_air=False, alt=0.0)
    w.error(7.6, "a", 14, 1, "safety: velocity modified by separation; nearest b at 4.80 m")
    w.error(7.7, "b", 14, 1, "safety: velocity modified by separation; nearest a at 4.60 m")
    w.error(
        4.5, "d", 14, 2, "safety: velocity modified by fence; outside the fence polygon by 2.5 m: flying back"
    )
    w.error(0.1, "d", 14, 0, "safety: fence mirrored into the autopilot and read back: FENCE_RADIUS 30")
    w.error(1.0, "d", 3, 1, "takeoff refused: battery low")  # not a SAFETY report
    return w.write(tmp_path / "head-on.lcm")


def test_separation_near_misses_breaches_reports_and_the_mission(tmp_path: Path) -> None:
    result = analyze_log(
        head_on(tmp_path),
        safety=SafetyLimits(5.0, None, 0.5, None, FENCE, (LAT0, LON0)),
    ).safety
    assert result is not None
    # a and b: 20 - 2t < 5 from t > 7.5 s; c is on the ground (never a pair); 4.0 m at 8.0 s
    assert result.min_separation == pytest.approx(4.0, abs=0.01)
    assert result.min_pair == ("a", "b") and result.min_t == pytest.approx(8.0)
    [miss] = result.near_misses
    assert (miss.a, miss.b) == ("a", "b")
    assert miss.start == pytest.approx(7.6) and miss.end == pytest.approx(8.0)
    assert miss.distance == pytest.approx(4.0, abs=0.01)
    assert result.losses == [miss]  # 4.0 < 5 - 0.5
    # d leaves through the east edge after 4 s and is 20 m out at 8 s; e below the floor under 1 m is landing
    [breach] = result.breaches
    # (its last report at 8.0 s still counts at the log's last sample, 8.05 s: within --max-age)
    assert breach.a == "d" and breach.start == pytest.approx(3.6) and breach.end == pytest.approx(8.05)
    assert breach.distance == pytest.approx(22.25, abs=0.05) and breach.t == pytest.approx(8.0)
    assert breach.what == "outside the fence polygon by 22.3 m"
    assert result.events_by_kind == {"separation": 2, "outside fence": 1, "fence mirror": 1}
    assert result.events_by_agent == {"a": 1, "b": 1, "d": 2}
    assert sorted(result.flew_mission) == list("abcde")
    assert sorted(result.landed) == ["a", "b", "c", "e"]  # d's last telemetry is in the air


def test_the_ellipsoid_counts_vertical_room(tmp_path: Path) -> None:
    """Two agents 2 m above one another: a loss of a 3 m separation as a sphere, 4 m with a 1.5 m half-height."""
    w = LogWriter()
    for k in range(11):
        w.telemetry(k / 10, "low", 0.0, 0.0, alt=5.0)
        w.telemetry(k / 10, "high", 0.0, 0.0, alt=7.0)
    log = w.write(tmp_path / "stacked.lcm")
    sphere = analyze_log(log, safety=SafetyLimits(3.0)).safety
    ellipsoid = analyze_log(log, safety=SafetyLimits(3.0, 1.5)).safety
    assert sphere is not None and ellipsoid is not None
    assert sphere.min_separation == pytest.approx(2.0) and len(sphere.near_misses) == 1
    assert ellipsoid.min_separation == pytest.approx(4.0) and ellipsoid.near_misses == []
    assert ellipsoid.min_separation_3d == pytest.approx(2.0)


def test_far_apart_agents_still_have_an_exact_minimum(tmp_path: Path) -> None:
    w = LogWriter()
    for k in range(5):
        w.telemetry(k / 10, "x", 0.0, 0.0)
        w.telemetry(k / 10, "y", 0.0, 100.0)
    result = analyze_log(w.write(tmp_path / "far.lcm"), safety=SafetyLimits(3.0)).safety
    assert result is not None and result.min_separation == pytest.approx(100.0, abs=0.01)


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ("safety: velocity modified by separation; nearest b at 4.80 m", "separation"),
        ("safety: velocity modified by fence; nearest b at 9.00 m", "fence"),
        ("safety: velocity modified by fence+separation; nearest b at 3.10 m", "fence+separation"),
        (
            "safety: velocity modified by separation; cannot keep separation (b): inside the margin",
            "conflict",
        ),
        (
            "safety: velocity modified by fence; above the fence ceiling (31.0 m > 30 m): flying back",
            "outside fence",
        ),
        ("safety: no peer information: 0 fresh peer(s) of min_peers 1", "no peers"),
        ("safety: fence mirrored into the autopilot and read back: FENCE_RADIUS 66", "fence mirror"),
        ("safety: the autopilot does not hold the fence (FENCE_ENABLE = 0, wanted 1)", "fence mirror"),
        ("something else", "other"),
    ],
)
def test_report_kinds(text: str, kind: str) -> None:
    assert event_kind(text) == kind


def test_the_reader_keeps_only_safety_reports(tmp_path: Path) -> None:
    record = read_log(head_on(tmp_path))
    assert [(e.agent, e.severity) for e in record.safety_events] == [("d", 0), ("d", 2), ("a", 1), ("b", 1)]


def test_cli_with_a_config_prints_the_safety_section(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "swarm.toml"
    cfg.write_text(
        tomli_w.dumps(
            {
                "agent": {"name": "a"},
                "hlc": {"autopilot": "sim"},
                "safety": {
                    "enabled": True,
                    "radius": 5.0,
                    "origin": [LAT0, LON0],
                    "fence": {"polygon": [list(p) for p in FENCE.polygon], "ceiling": 30.0, "margin": 2.0},
                },
            }
        )
    )
    assert main(["analyze", str(head_on(tmp_path)), "--safety", str(cfg)]) == 0
    out = capsys.readouterr().out
    # the sim's half-height (1.5 m) and measured margin (0.5 m) come from the vehicle's defaults
    assert "safety (radius 5 m, half-height 1.5 m, documented margin 0.5 m" in out
    assert "min separation     4.00 m at 8.0 s (a, b; 3-D 4.00 m)" in out
    assert "radius - margin = 4.50 m: BELOW" in out
    assert "1 encounter(s) closer than 5 m, 1 closer than 4.50 m (losses of separation)" in out
    assert (
        "fence breaches     1" in out and "d: 3.6 .. 8.1 s, worst at 8.0 s: outside the fence polygon" in out
    )
    assert "SAFETY reports     4 (fence mirror 1, outside fence 1, separation 2) from 3 agent(s)" in out
    assert "5 of 5 agent(s) flew MISSION; 4 back in STANDBY on the ground at the end" in out


def test_cli_radius_alone_and_options_that_need_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = head_on(tmp_path)
    assert main(["analyze", str(log), "--radius", "3"]) == 0
    out = capsys.readouterr().out
    assert "safety (radius 3 m, 3-D distance, documented margin 0 m" in out
    assert "0 encounter(s) closer than 3 m" in out and "fence breaches     - (no fence given)" in out
    assert main(["analyze", str(log), "--margin", "0.5"]) == 2
    assert "--margin needs --radius or --safety CONFIG" in capsys.readouterr().err
    assert main(["analyze", str(log)]) == 0
    assert "safety (radius" not in capsys.readouterr().out  # no limits, no section


def test_cli_json_holds_the_safety_numbers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    assert main(["analyze", str(head_on(tmp_path)), "--radius", "5", "--margin", "0.5", "--json"]) == 0
    safety = json.loads(capsys.readouterr().out)["safety"]
    assert safety["min_separation"] == pytest.approx(4.0, abs=0.01) and safety["min_pair"] == ["a", "b"]
    assert [(m["a"], m["b"]) for m in safety["near_misses"]] == [("a", "b")]
    assert safety["limits"] == {
        "radius": 5.0,
        "vertical": None,
        "margin": 0.5,
        "near_miss": None,
        "fence": None,
        "origin": None,
    }
