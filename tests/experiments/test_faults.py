"""Faults injected by an experiment's script, and lossy broadcast control (``antalate run``,
docs/experiments.md "Faults" and "Lossy broadcasts").

The flights are real: the agents' MC, HLC and BMA nodes with ``direction_follow`` and the simulated
peer sensor, a scripted operator and a recorder on ``memq://`` in this process; every assertion is
read from the recorded log (the fault records, the telemetry, the MC states, the peer scans), as a
researcher would read it. The reception rate is measured at the admission of one agent over 5,000
messages against the exact 99 % binomial interval.
"""

from __future__ import annotations

import bisect
import json
import math
import re
import statistics
import time
from pathlib import Path
from typing import Any

import lcm
import pytest

from antalate_lcm.apps.analysis import analyze_log, format_summary, read_log
from antalate_lcm.apps.analysis.records import FaultRecord, SwarmRecord
from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import load_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import mc_state_t, operator_cmd_t, peer_scan_t, telemetry_t
from antalate_lcm.runtime.experiment import Experiment, Outcome, run
from antalate_lcm.runtime.faults import BroadcastReception, FaultGate, plan
from antalate_lcm.runtime.script import Script, load_script, parse_script
from tests.harness.agents import swarm_config
from tests.harness.cases import cases

BEHAVIORS = (
    {"plugin": "direction_follow"},
    {"plugin": "peer_sensor", "params": {"max_range": 1000.0, "identities": True}},
)
CONFIG = swarm_config("e", *BEHAVIORS)
#: The same swarm on the namespace's multicast group, for runs over several processes.
UDPM_CONFIG = swarm_config("e", *BEHAVIORS, bus="udpm://239.255.76.67:7667?ttl=0")

#: Every swarm flies east at 2 m/s from the start of its mission (the agents keep their grid).
EAST = "[[direction]]\nat = 0.0\nazimuth = 90.0\nspeed = 2.0\n"


def _fly(tmp_path: Path, name: str, agents: int, script_text: str) -> tuple[Outcome, SwarmRecord]:
    config = tmp_path / "swarm.toml"
    config.write_text(CONFIG)
    script = _script(tmp_path / f"{name}.toml", script_text)
    out = tmp_path / f"{name}.lcm"
    outcome = run(Experiment(str(config), agents=agents, script=script, output=str(out), log_level="WARNING"))
    return outcome, read_log(out)


def _script(path: Path, text: str) -> Script:
    path.write_text(text)
    return load_script(path)


def _faults(record: SwarmRecord, agent: str, kind: str) -> dict[str, FaultRecord]:
    return {f.event: f for f in record.faults if f.agent == agent and f.kind == kind}


def _span(record: SwarmRecord, agent: str, kind: str) -> tuple[float, float]:
    """When the agent's fault of ``kind`` started and ended (s into the log)."""
    fault = _faults(record, agent, kind)
    return fault["start"].t, fault["end"].t


def _ne(record: SwarmRecord, agent: str) -> list[tuple[float, float, float]]:
    """(t, north, east) of the agent's telemetry, in one frame for every agent."""
    frame = FlatFrame(32.7767, 35.0231)
    return [(s.t, *frame.to_ne(s.lat, s.lon)) for s in record.agents[agent].telemetry]


def _gap(
    a: list[tuple[float, float, float]], b: list[tuple[float, float, float]], axis: int, t0: float, t1: float
) -> float:
    """The median of a - b along ``axis`` (1 north, 2 east) over a's samples in (t0, t1), each
    against b's sample nearest in time."""
    tb = [s[0] for s in b]
    out = []
    for s in a:
        if t0 < s[0] < t1:
            i = min(bisect.bisect_left(tb, s[0]), len(tb) - 1)
            j = i - 1 if i > 0 and abs(tb[i - 1] - s[0]) < abs(tb[i] - s[0]) else i
            out.append(s[axis] - b[j][axis])
    assert out
    return statistics.median(out)


def _raw(path: Path, channel: str) -> list[tuple[float, Any]]:
    """(log time in s, decoded message) of every event on ``channel``, as the recorder heard it."""
    types: dict[str, Any] = {"TELEMETRY": telemetry_t, "PEER_SCAN": peer_scan_t}
    msg_type = types[channel.split("/")[1]]
    out = []
    start = None
    for event in lcm.EventLog(str(path), "r"):
        start = event.timestamp if start is None else start
        if event.channel == channel:
            out.append(((event.timestamp - start) / 1e6, msg_type.decode(event.data)))
    return out


# ----------------------------------------------------------------------------- the script
@pytest.mark.parametrize(("fault", "key", "what"), cases("experiments/bad_faults.toml"))
def test_a_bad_fault_is_one_line_naming_the_key(tmp_path: Path, fault: str, key: str, what: str) -> None:
    with pytest.raises(ConfigError) as info:
        _script(tmp_path / "s.toml", f"mission_time = 6\n[[fault]]\n{fault}\n")
    assert info.value.key == key and what in str(info.value), str(info.value)
    assert "\n" not in str(info.value) and "s.toml" in str(info.value)


def test_bad_broadcast_and_seed_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"broadcast\.reception: .*less than or equal to 1"):
        parse_script({"mission_time": 6, "broadcast": {"reception": 1.2}}, "s.toml")
    with pytest.raises(ConfigError, match=r"seed: .*greater than or equal to 0"):
        parse_script({"mission_time": 6, "seed": -1}, "s.toml")


def test_faults_on_unknown_agents_or_elsewhere_fail_before_anything_flies(tmp_path: Path) -> None:
    config = tmp_path / "swarm.toml"
    config.write_text(CONFIG)
    crash = {"kind": "crash", "agent": "e-07", "at": 1.0}
    script = parse_script({"mission_time": 6, "fault": [crash]}, "s.toml")
    out = tmp_path / "x.lcm"
    with pytest.raises(ConfigError) as info:
        run(Experiment(str(config), agents=3, script=script, output=str(out), script_source="s.toml"))
    assert info.value.key == "fault[0].agent" and "'e-07'" in str(info.value) and "e-01" in str(info.value)
    script = parse_script({"mission_time": 6, "fault": [{**crash, "agent": "e-01"}]}, "s.toml")
    with pytest.raises(AntalateError, match=r"needs --headless"):
        run(Experiment(str(config), agents=3, script=script, output=str(out), headless=False))
    mavlink = _write(tmp_path / "mavlink.toml", swarm_config("e", *BEHAVIORS, autopilot="mavlink"))
    for kind, keys in (("battery", {"level": 10.0}), ("vehicle", {"vehicle": "failsafe"})):
        fault = {"kind": kind, "agent": "e", "at": 1.0, **keys}
        script = parse_script({"mission_time": 6, "fault": [fault]}, "s.toml")
        with pytest.raises(ConfigError, match=rf"fault\[0\]\.kind: a {kind} fault on a simulated vehicle"):
            run(Experiment(str(mavlink), script=script, output=str(out), script_source="s.toml"))
    assert not out.exists()


def test_the_cli_names_the_script_and_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from antalate_lcm.cli import main

    config = _write(tmp_path / "swarm.toml", CONFIG)
    script = _write(
        tmp_path / "s.toml", 'mission_time = 6\n[[fault]]\nkind = "freeze"\nagent = ["e-01", "e-9"]\nat = 1\n'
    )
    out = tmp_path / "x.lcm"
    argv = ["run", str(config), "--agents", "2", "--headless", "--script", str(script), "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{script}: fault[0].agent" in err and "(got 'e-9')" in err
    assert not out.exists()


# ----------------------------------------------------------------------------- pure: draws
def _binomial_99(n: int, p: float) -> tuple[int, int]:
    """The exact central 99 % interval of Binomial(n, p): [lo, hi] with P(X < lo), P(X > hi) <= 0.5 %."""
    cdf, lo, hi = 0.0, None, n
    for k in range(n + 1):
        log_pmf = math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)
        cdf += math.exp(log_pmf + k * math.log(p) + (n - k) * math.log1p(-p))
        if lo is None and cdf > 0.005:
            lo = k
        if cdf >= 0.995:
            hi = k
            break
    assert lo is not None
    return lo, hi


@pytest.mark.parametrize("p", [0.1, 0.5, 0.85])
def test_broadcast_reception_rate_lies_in_the_binomial_interval(p: float) -> None:
    n = 5000
    reception = BroadcastReception(p, seed=7, agent="e-01")
    heard = sum(reception.admit(("SWARM_DIRECTION_CMD", "operator", seq, seq * 1000)) for seq in range(n))
    lo, hi = _binomial_99(n, p)
    assert lo <= heard <= hi, (heard, lo, hi)
    assert (reception.offered, reception.heard) == (n, heard)


def test_broadcast_reception_is_per_message_per_agent_and_reproducible() -> None:
    keys = [("SWARM_OPERATOR_CMD", "operator", seq, seq) for seq in range(2000)]

    def draws(seed: int, agent: str) -> list[bool]:
        reception = BroadcastReception(0.5, seed, agent)
        return [reception.admit(k) for k in keys]

    a, again, other_seed, b = draws(1, "e-01"), draws(1, "e-01"), draws(2, "e-01"), draws(1, "e-02")
    assert a == again and a != other_seed and a != b
    # independent agents: both hear a message with probability p * p
    lo, hi = _binomial_99(len(keys), 0.25)
    assert lo <= sum(x and y for x, y in zip(a, b, strict=True)) <= hi
    # every node of one agent that consumes one message gets one answer (a resend is a new chance)
    one = BroadcastReception(0.5, 1, "e-03")
    first = [one.admit(k) for k in keys[:50]]
    assert [one.admit(k) for k in keys[:50]] == first and one.offered == 50
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        BroadcastReception(1.5, 1, "e-01")


def test_random_fault_times_are_drawn_per_agent_from_the_seed() -> None:
    def script(seed: int, **extra: Any) -> Script:
        fault = {"kind": "crash", "agent": "*", "at": 2.0, "probability": 0.5, **extra}
        return Script.model_validate({"mission_time": 9.0, "seed": seed, "fault": [fault]})

    names = [f"a-{i:03d}" for i in range(1, 1001)]
    drawn = plan(script(4, at_latest=6.0), names)
    times = [p.at for p in drawn]
    assert 2.0 <= min(times) < 2.1 and 5.9 < max(times) <= 6.0
    assert statistics.mean(times) == pytest.approx(4.0, abs=0.15)  # uniform: sd of the mean 0.04
    assert [p.at for p in plan(script(4, at_latest=6.0), names)] == times
    assert [p.at for p in plan(script(5, at_latest=6.0), names)] != times
    # who is hit does not depend on when: the same agents as with a fixed time
    assert [p.hit for p in drawn] == [p.hit for p in plan(script(4), names)]
    assert {p.at for p in plan(script(4), names)} == {2.0}
    # a run may be longer than its mission: from the start of the run, any time is fine
    late = {"kind": "crash", "agent": "*", "at": 30.0, "since": "start"}
    assert parse_script({"mission_time": 5.0, "fault": [late]}, "s.toml").fault[0].at == 30.0


def test_fault_probability_hits_agents_reproducibly() -> None:
    script = Script.model_validate(
        {
            "mission_time": 9.0,
            "seed": 4,
            "fault": [
                {"kind": "crash", "agent": "*", "at": 1.0, "probability": 0.3},
                {"kind": "freeze", "agent": ["a-001", "a-002"], "at": 2.0, "duration": 1.0},
                {"kind": "link_loss", "agent": "a-003", "at": 2.0, "probability": 0.0},
            ],
        }
    )
    names = [f"a-{i:03d}" for i in range(1, 1001)]
    planned = plan(script, names)
    crashes = [p for p in planned if p.step.kind == "crash"]
    assert len(crashes) == 1000 and [p.agent for p in planned if p.step.kind == "freeze"] == [
        "a-001",
        "a-002",
    ]
    lo, hi = _binomial_99(1000, 0.3)
    assert lo <= sum(p.hit for p in crashes) <= hi
    assert all(p.hit for p in planned if p.step.kind == "freeze")
    assert not any(p.hit for p in planned if p.step.kind == "link_loss")
    assert [p.hit for p in plan(script, names)] == [p.hit for p in planned]
    reseeded = plan(script.model_copy(update={"seed": 5}), names)
    assert [p.hit for p in reseeded] != [p.hit for p in planned]


# ----------------------------------------------------------------------------- the gate, message by message
def _gate_with(tmp_path: Path, fault: dict[str, Any]) -> tuple[FaultGate, Node, Node]:
    """A gate with ``fault`` active on agent e-01, and e-01's node and the operator's (never started; a
    plain `Node` declared a watcher, as the scripted operator and the console are: the gate reads the
    role the node declared, not its kind)."""
    config = load_config(_write(tmp_path / "swarm.toml", CONFIG))
    context = Context(Buses({"lan": "memq://"}), Executor())
    script = Script.model_validate({"mission_time": 9.0, "fault": [{"agent": "e-01", "at": 0.0, **fault}]})
    gate = FaultGate()
    (planned,) = plan(script, ["e-01", "e-02"])
    gate.activate(planned.step, 0, "e-01", seed=1)
    return (
        gate,
        Node(NodeSettings.from_config(config, agent="e-01"), context),
        Node(NodeSettings.from_config(config, agent="operator"), context, watcher=True),
    )


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _from(agent: str, seq: int, msg: Any = None) -> Any:
    msg = msg if msg is not None else telemetry_t()
    msg.header.agent, msg.header.seq, msg.header.utime = agent, seq, seq
    return msg


def test_packet_loss_in_drops_what_the_agent_hears_from_others_only(tmp_path: Path) -> None:
    gate, node, _ = _gate_with(
        tmp_path, {"kind": "packet_loss", "topics": ["TELEMETRY"], "loss": 0.4, "direction": "in"}
    )
    heard: list[Any] = []
    receive = gate.receiving(node, "TELEMETRY", heard.append)
    for seq in range(2000):
        receive(_from("e-02", seq))
    lo, hi = _binomial_99(2000, 0.6)
    assert lo <= len(heard) <= hi
    heard.clear()
    for seq in range(100):  # its own telemetry is not from the network
        receive(_from("e-01", seq))
    assert len(heard) == 100
    other_topic = gate.receiving(node, "MC_STATE", heard.append)
    heard.clear()
    for seq in range(100):
        other_topic(_from("e-02", seq, mc_state_t()))
    assert len(heard) == 100


def test_a_bandwidth_cap_on_what_an_agent_hears_passes_its_bucket_only(tmp_path: Path) -> None:
    gate, node, _ = _gate_with(
        tmp_path,
        {
            "kind": "packet_loss",
            "topics": ["TELEMETRY"],
            "bandwidth": 100.0,
            "burst": 500.0,
            "direction": "in",
        },
    )
    heard: list[Any] = []
    receive = gate.receiving(node, "TELEMETRY", heard.append)
    size = len(_from("e-02", 0).encode())
    for seq in range(50):  # at once: the bucket's 500 bytes, and the trickle of 100 bytes/s meanwhile
        receive(_from("e-02", seq))
    assert len(heard) in (500 // size, 500 // size + 1), (len(heard), size)
    heard.clear()
    for seq in range(50):  # its own telemetry does not come from the network
        receive(_from("e-01", seq))
    assert len(heard) == 50


def test_link_loss_cuts_both_sides_and_nothing_else(tmp_path: Path) -> None:
    gate, node, operator = _gate_with(tmp_path, {"kind": "link_loss"})
    reception = gate.broadcast["e-01"] = BroadcastReception(1.0, 1, "e-01")
    heard: list[Any] = []
    for topic in ("SWARM_OPERATOR_CMD", "OPERATOR_CMD", "SWARM_DIRECTION_CMD"):
        gate.receiving(node, topic, heard.append)(_from("operator", 1, operator_cmd_t()))
    assert heard == []
    gate.receiving(node, "TELEMETRY", heard.append)(_from("e-02", 1))  # peers still reach it
    gate.receiving(operator, "MC_STATE", heard.append)(
        _from("e-01", 1, mc_state_t())
    )  # the operator hears nothing
    gate.receiving(operator, "MC_STATE", heard.append)(_from("e-02", 1, mc_state_t()))
    assert [m.header.agent for m in heard] == ["e-02", "e-02"]
    assert not gate.silenced("e-01") and gate.link_lost("e-01") and not gate.link_lost("e-02")
    (step,) = gate.active["e-01"]["link_loss"]
    gate.deactivate(step.step, 0, "e-01")
    gate.receiving(node, "OPERATOR_CMD", heard.append)(_from("operator", 2, operator_cmd_t()))
    assert len(heard) == 3 and gate.active == {}
    assert reception.offered == 0  # the broadcasts of the outage were never offered to it
    gate.receiving(node, "SWARM_OPERATOR_CMD", heard.append)(_from("operator", 3, operator_cmd_t()))
    assert len(heard) == 4 and (reception.offered, reception.heard) == (1, 1)


# ----------------------------------------------------------------------------- flights
@pytest.fixture(scope="module")
def dead_and_frozen(tmp_path_factory: pytest.TempPathFactory) -> tuple[Outcome, SwarmRecord]:
    """5 agents east at 2 m/s: e-01 crashes, e-02 freezes 2 s, e-03's position reads 20 m north
    for 2 s, e-04 claims HOLD for 2 s while flying its mission, e-05's vehicle lands on a failsafe."""
    return _fly(
        tmp_path_factory.mktemp("faults-a"),
        "a",
        5,
        "mission_time = 8.0\n"
        + EAST
        + '[[fault]]\nkind = "crash"\nagent = "e-01"\nat = 2.0\n'
        + '[[fault]]\nkind = "freeze"\nagent = "e-02"\nat = 2.0\nduration = 2.0\n'
        + '[[fault]]\nkind = "sensor"\nsensor = "position"\nmode = "bias"\noffset = [20.0, 0.0]\n'
        + 'agent = "e-03"\nat = 3.0\nduration = 2.0\n'
        + '[[fault]]\nkind = "byzantine"\nstate = "HOLD"\nagent = "e-04"\nat = 1.0\nduration = 2.0\n'
        + '[[fault]]\nkind = "vehicle"\nvehicle = "failsafe"\nfailsafe = "land"\nagent = "e-05"\nat = 2.0\n',
    )


def test_each_fault_is_recorded_when_and_for_whom_the_script_says(
    dead_and_frozen: tuple[Outcome, SwarmRecord],
) -> None:
    outcome, record = dead_and_frozen
    # the operator waits no more for the crashed agent; every other one came back
    assert outcome.code == 0, outcome.report
    assert "e-01: " in outcome.report and "(lost to a fault of the script)" in outcome.report
    got = [(f.agent, f.kind, f.event) for f in record.faults]
    assert sorted(got) == sorted(
        [
            ("e-01", "crash", "start"),
            ("e-02", "freeze", "start"),
            ("e-02", "freeze", "end"),
            ("e-03", "sensor", "start"),
            ("e-03", "sensor", "end"),
            ("e-04", "byzantine", "start"),
            ("e-04", "byzantine", "end"),
            ("e-05", "vehicle", "start"),
        ]
    )
    mission = max(next(c.t for c in rec.mc_states if c.state == "MISSION") for rec in record.agents.values())
    for f in record.faults:  # at the script's time (s after the whole swarm entered MISSION)
        due = {"crash": 2.0, "freeze": 2.0, "sensor": 3.0, "byzantine": 1.0, "vehicle": 2.0}[f.kind]
        due += float(str(f.detail.get("duration", 0.0))) if f.event == "end" else 0.0
        assert due <= f.t - mission <= due + 1.0, (f, mission)
        assert f.detail["at"] == pytest.approx(due, abs=0.2)
    # antalate analyze lists them
    text = analyze_log(record.path).faults
    assert [(f.agent, f.kind, f.event) for f in text] == got


def test_a_crashed_agent_falls_silent_for_good(dead_and_frozen: tuple[Outcome, SwarmRecord]) -> None:
    _, record = dead_and_frozen
    crash = _faults(record, "e-01", "crash")["start"]
    assert crash.t - 1.0 < record.agents["e-01"].last_heard <= crash.t + 0.1
    assert record.agents["e-01"].mc_states[-1].state == "MISSION"  # never RTL: nobody is there to do it
    assert record.agents["e-02"].last_heard > crash.t + 5.0


def test_a_frozen_agent_is_silent_for_the_duration_then_carries_on(
    dead_and_frozen: tuple[Outcome, SwarmRecord],
) -> None:
    _, record = dead_and_frozen
    start, end = _span(record, "e-02", "freeze")
    times = [s.t for s in record.agents["e-02"].telemetry]
    assert not [t for t in times if start + 0.1 < t < end - 0.1]
    assert [t for t in times if t > end + 0.3]
    assert record.agents["e-02"].mc_states[-1].state == "STANDBY"


def test_a_biased_position_sensor_moves_the_agent_in_its_telemetry(
    dead_and_frozen: tuple[Outcome, SwarmRecord],
) -> None:
    _, record = dead_and_frozen
    start, end = _span(record, "e-03", "sensor")
    # e-03 and e-04 fly east side by side: what changes between them is e-03's reading
    e3, e4 = _ne(record, "e-03"), _ne(record, "e-04")

    def gap(t0: float, t1: float) -> float:
        pairs = [(a[1] - b[1]) for a, b in zip(e3, e4, strict=False) if t0 < a[0] < t1]
        assert pairs
        return statistics.median(pairs)

    before, during, after = (
        gap(start - 1.0, start - 0.1),
        gap(start + 0.3, end - 0.3),
        gap(end + 0.3, end + 1.0),
    )
    assert during - before == pytest.approx(20.0, abs=1.0)
    assert after - before == pytest.approx(0.0, abs=1.0)


def test_a_byzantine_agent_claims_a_state_it_is_not_in(dead_and_frozen: tuple[Outcome, SwarmRecord]) -> None:
    outcome, record = dead_and_frozen
    start, end = _span(record, "e-04", "byzantine")
    states = [(c.t, c.state) for c in record.agents["e-04"].mc_states]
    (hold,) = [(t, s) for t, s in states if s == "HOLD"]
    assert start - 0.1 <= hold[0] <= start + 1.0
    assert any(s == "MISSION" and end - 0.1 <= t <= end + 1.0 for t, s in states)
    assert "HOLD" in outcome.report  # the operator believed it too
    # ... while its own nodes knew the truth: it flew on east at the commanded speed
    during = [s.ve for s in record.agents["e-04"].telemetry if start + 0.3 < s.t < end]
    assert during and min(during) > 1.5


def test_a_vehicle_failsafe_lands_the_agent(dead_and_frozen: tuple[Outcome, SwarmRecord]) -> None:
    outcome, record = dead_and_frozen
    fault = _faults(record, "e-05", "vehicle")["start"]
    assert fault.detail["vehicle"] == "failsafe" and fault.detail["failsafe"] == "land"
    states = [(c.t, c.state) for c in record.agents["e-05"].mc_states]
    land = next(t for t, s in states if s == "LAND")
    assert fault.t - 0.1 <= land <= fault.t + 1.5
    assert "RTL" not in [s for _, s in states] and states[-1][1] == "STANDBY"
    assert not record.agents["e-05"].telemetry[-1].in_air
    assert "fault: vehicle failsafe start e-05" in outcome.report


def test_the_plot_marks_the_faults_on_their_agents(dead_and_frozen: tuple[Outcome, SwarmRecord]) -> None:
    from antalate_lcm.apps.analysis.plot import figure

    _, record = dead_and_frozen
    analysis = analyze_log(record.path)
    timelines = figure(record, analysis, analysis.tracks).axes[1]
    assert timelines.get_title().endswith("; black: faults)")
    marks: dict[str, Any] = {t.get_text(): getattr(t, "xy", None) for t in timelines.texts}
    assert set(marks) == {"crash", "freeze", "sensor position", "byzantine", "vehicle failsafe"}
    crash = _faults(record, "e-01", "crash")["start"]
    assert marks["crash"] == (crash.t, pytest.approx(0.35))  # on e-01's row, at its time


def test_faults_before_the_mission_and_at_random_times(tmp_path: Path) -> None:
    """e-01 crashes as the run starts, on the ground: the operator takes off the others and waits
    no more for it; e-02 freezes from 0.5 s of the run for 1 s, while the swarm takes off; e-03's
    position is biased from a time drawn in [0.5, 1.5] s of the mission."""
    script_text = (
        "mission_time = 3.0\nseed = 6\n"
        + EAST
        + '[[fault]]\nkind = "crash"\nagent = "e-01"\nat = 0.0\nsince = "start"\n'
        + '[[fault]]\nkind = "freeze"\nagent = "e-02"\nat = 0.5\nduration = 1.0\nsince = "start"\n'
        + '[[fault]]\nkind = "sensor"\nsensor = "position"\nmode = "bias"\noffset = [20.0, 0.0]\n'
        + 'agent = "e-03"\nat = 0.5\nat_latest = 1.5\nduration = 1.0\n'
    )
    outcome, record = _fly(tmp_path, "early", 3, script_text)
    assert outcome.code == 0, outcome.report
    assert re.search(r"fault: crash start e-01 at 0\.[01] s of the run", outcome.report), outcome.report
    states = {a: [c.state for c in rec.mc_states] for a, rec in record.agents.items()}
    assert "TAKEOFF" not in states["e-01"]  # it never left the ground
    assert states["e-02"][-1] == states["e-03"][-1] == "STANDBY" and "MISSION" in states["e-02"]
    mission = max(
        next(c.t for c in record.agents[a].mc_states if c.state == "MISSION") for a in ("e-02", "e-03")
    )
    crash = _faults(record, "e-01", "crash")["start"]
    freeze = _faults(record, "e-02", "freeze")
    assert crash.t < freeze["start"].t < mission and crash.detail["since"] == "start"
    assert freeze["end"].t - freeze["start"].t == pytest.approx(1.0, abs=0.2)
    # the drawn time is plan()'s, counted from the mission's start, and recorded
    (drawn,) = [
        p.at for p in plan(load_script(tmp_path / "early.toml"), ["e-01", "e-02", "e-03"]) if p.index == 2
    ]
    bias = _faults(record, "e-03", "sensor")["start"]
    assert 0.5 <= drawn <= 1.5 and bias.detail["at"] == pytest.approx(drawn, abs=0.1)
    assert bias.detail["at_latest"] == 1.5
    assert drawn - 0.05 <= bias.t - mission <= drawn + 0.6


@pytest.fixture(scope="module")
def lossy(tmp_path_factory: pytest.TempPathFactory) -> tuple[Outcome, SwarmRecord]:
    """5 agents east at 2 m/s: e-01 lies 30 m east of itself, then loses the operator over the
    RTL; e-02 loses half its telemetry and delays the rest 0.4 s; e-03's battery drops to 30 %
    and drains 60 %/min; e-04's peer sensor reads 5 m long; e-05's position sticks, and a crash
    with probability 0 spares it; e-06's telemetry out is capped at 500 bytes/s."""
    return _fly(
        tmp_path_factory.mktemp("faults-b"),
        "b",
        6,
        "mission_time = 7.0\nseed = 11\n"
        + EAST
        + '[[fault]]\nkind = "byzantine"\noffset = [0.0, 30.0]\nagent = "e-01"\nat = 1.0\nduration = 2.0\n'
        + '[[fault]]\nkind = "link_loss"\nagent = "e-01"\nat = 5.0\nduration = 4.0\n'
        + '[[fault]]\nkind = "packet_loss"\nagent = "e-02"\nat = 1.0\nduration = 3.0\n'
        + 'topics = ["TELEMETRY"]\nloss = 0.5\ndelay = 0.4\ndirection = "out"\n'
        + '[[fault]]\nkind = "battery"\nagent = "e-03"\nat = 1.0\nlevel = 30.0\ndrain = 60.0\n'
        + '[[fault]]\nkind = "sensor"\nsensor = "peers"\nmode = "bias"\nrange_bias = 5.0\n'
        + 'agent = "e-04"\nat = 1.0\nduration = 3.0\n'
        + '[[fault]]\nkind = "sensor"\nsensor = "position"\nmode = "stuck"\nagent = "e-05"\nat = 1.0\n'
        + "duration = 2.0\n"
        + '[[fault]]\nkind = "crash"\nagent = "e-05"\nat = 4.0\nprobability = 0.0\n'
        + '[[fault]]\nkind = "packet_loss"\nagent = "e-06"\nat = 1.0\nduration = 4.0\n'
        + 'topics = ["TELEMETRY"]\nbandwidth = 500.0\nburst = 200.0\ndirection = "out"\n',
    )


def test_the_lossy_flight_comes_back_with_every_fault_recorded(lossy: tuple[Outcome, SwarmRecord]) -> None:
    outcome, record = lossy
    assert outcome.code == 0, outcome.report
    assert {(f.agent, f.kind) for f in record.faults if f.event == "start"} == {
        ("e-01", "byzantine"),
        ("e-01", "link_loss"),
        ("e-02", "packet_loss"),
        ("e-03", "battery"),
        ("e-04", "sensor"),
        ("e-05", "sensor"),
        ("e-06", "packet_loss"),
    }
    assert "link_loss start e-01" in outcome.report
    # a fault whose probability drew no hit is recorded as spared, and spares the agent
    (spared,) = [f for f in record.faults if f.kind == "crash"]
    assert (spared.agent, spared.event) == ("e-05", "spared")
    assert record.agents["e-05"].mc_states[-1].state == "STANDBY"


def test_a_byzantine_position_fools_the_others_not_itself(lossy: tuple[Outcome, SwarmRecord]) -> None:
    _, record = lossy
    start, end = _span(record, "e-01", "byzantine")
    e1, e4 = _ne(record, "e-01"), _ne(record, "e-04")
    assert _gap(e1, e4, 2, start + 0.3, end - 0.3) - _gap(
        e1, e4, 2, start - 1.0, start - 0.1
    ) == pytest.approx(30.0, abs=1.5)
    path = Path(record.path)

    def ranges(scanner: str, peer: str, t0: float, t1: float) -> list[float]:
        out = []
        for t, scan in _raw(path, f"{scanner}/PEER_SCAN"):
            if t0 < t < t1 and peer in scan.id:
                out.append(float(scan.range[list(scan.id).index(peer)]))
        assert out
        return out

    # e-01's own sensor measures from where it really is: its range to e-04 does not jump...
    own_before, own_during = (
        ranges("e-01", "e-02", start - 1.0, start),
        ranges("e-01", "e-02", start + 0.3, end),
    )
    assert max(own_during) - min(own_before) < 2.0
    # ... e-02's does: it believes e-01 moved 30 m east, from 8 m west of it to 22 m east
    other_before = statistics.median(ranges("e-02", "e-01", start - 1.0, start))
    other_during = statistics.median(ranges("e-02", "e-01", start + 0.3, end))
    assert other_before == pytest.approx(8.0, abs=1.0) and other_during == pytest.approx(22.0, abs=1.5)


def test_link_loss_keeps_the_operators_rtl_from_the_agent(lossy: tuple[Outcome, SwarmRecord]) -> None:
    _, record = lossy
    link = _faults(record, "e-01", "link_loss")
    start, end = link["start"].t, link["end"].t

    def rtl(agent: str) -> float:
        return next(c.t for c in record.agents[agent].mc_states if c.state == "RTL")

    assert start < min(rtl(a) for a in ("e-02", "e-03", "e-04", "e-05")) < end  # the RTL fell in the outage
    assert end - 0.1 <= rtl("e-01") <= end + 2.5  # e-01 heard it once the link was back (resent every s)
    assert record.agents["e-01"].mc_states[-1].state == "STANDBY"


def test_packet_loss_and_delay_on_the_chosen_topic(lossy: tuple[Outcome, SwarmRecord]) -> None:
    _, record = lossy
    start, end = _span(record, "e-02", "packet_loss")
    path = Path(record.path)

    def window(agent: str, t0: float, t1: float) -> list[tuple[float, Any]]:
        return [(t, m) for t, m in _raw(path, f"{agent}/TELEMETRY") if t0 < t < t1]

    lossy2, clean3 = window("e-02", start + 0.5, end), window("e-03", start + 0.5, end)
    assert 0.2 < len(lossy2) / len(clean3) < 0.8, (len(lossy2), len(clean3))
    t_start = record.start_utime / 1e6

    def lag(samples: list[tuple[float, Any]]) -> float:  # log time - send time
        return statistics.median(t + t_start - float(m.header.utime) / 1e6 for t, m in samples)

    assert 0.39 < lag(lossy2) < 0.8
    assert lag(window("e-02", end + 1.0, end + 3.0)) < 0.2


def test_a_bandwidth_cap_holds_the_delivered_rate_under_it(lossy: tuple[Outcome, SwarmRecord]) -> None:
    """e-06 offers 10 telemetry messages a second (about 840 bytes/s); through a cap of 500 bytes/s
    (a bucket of 200 bytes) the log receives what the cap lets through, and no more."""
    _, record = lossy
    cap = _faults(record, "e-06", "packet_loss")
    start, end = cap["start"].t, cap["end"].t
    assert cap["start"].detail["bandwidth"] == 500.0 and cap["start"].detail["burst"] == 200.0
    sizes: dict[str, list[tuple[float, int]]] = {"e-06": [], "e-03": []}
    t0 = None
    for event in lcm.EventLog(record.path, "r"):
        t0 = event.timestamp if t0 is None else t0
        agent = event.channel.split("/")[0]
        if event.channel.endswith("/TELEMETRY") and agent in sizes:
            sizes[agent].append(((event.timestamp - t0) / 1e6, len(event.data)))

    def rate(agent: str, a: float, b: float) -> float:
        return sum(n for t, n in sizes[agent] if a <= t < b) / (b - a)

    window = (start + 0.2, end - 0.2)
    offered = rate("e-03", *window)  # an agent without a cap, the same messages
    delivered = rate("e-06", *window)
    assert offered > 700.0, offered
    # within the cap (what the bucket held at the start may come on top), and not far below it
    assert 0.75 * 500.0 < delivered <= 500.0 + 200.0 / (window[1] - window[0]), (delivered, offered)
    assert rate("e-06", end + 0.5, end + 2.0) > 700.0  # the cap ends with the fault


def test_a_battery_fault_drops_and_drains_the_sim_battery(lossy: tuple[Outcome, SwarmRecord]) -> None:
    _, record = lossy
    fault = _faults(record, "e-03", "battery")["start"]
    batt = [(s.t, s.battery) for s in record.agents["e-03"].telemetry]
    before = [b for t, b in batt if t < fault.t - 0.1]
    assert before and before[-1] > 90.0
    at = [b for t, b in batt if fault.t + 0.2 < t < fault.t + 0.5]
    later = [b for t, b in batt if fault.t + 3.0 < t < fault.t + 3.3]
    assert at and 28.0 < at[0] <= 30.0
    assert later and at[0] - later[0] == pytest.approx(3.0, abs=0.8)  # 60 %/min = 1 %/s in the air


def test_a_faulty_peer_sensor_and_a_stuck_position(lossy: tuple[Outcome, SwarmRecord]) -> None:
    _, record = lossy
    path = Path(record.path)
    start, end = _span(record, "e-04", "sensor")
    scans = _raw(path, "e-04/PEER_SCAN")

    def range_to(peer: str, t0: float, t1: float) -> float:
        return statistics.median(
            float(s.range[list(s.id).index(peer)]) for t, s in scans if t0 < t < t1 and peer in s.id
        )

    assert range_to("e-03", start + 0.3, end) - range_to("e-03", start - 1.0, start) == pytest.approx(
        5.0, abs=0.5
    )
    start, end = _span(record, "e-05", "sensor")
    during = {(round(n, 3), round(e, 3)) for t, n, e in _ne(record, "e-05") if start + 0.1 < t < end - 0.1}
    assert len(during) == 1  # flying east at 2 m/s, reading one place
    moved = [e for t, _, e in _ne(record, "e-05") if end + 0.2 < t < end + 1.0]
    (_, stuck_east) = during.pop()
    assert moved and moved[0] - stuck_east > 2.0


def test_lossy_broadcasts_reach_each_agent_with_the_configured_probability(tmp_path: Path) -> None:
    """Half the broadcasts reach each agent: the flight still flies (the operator repeats its
    commands every second while an agent has not followed), and each agent's reception is in the log."""
    outcome, record = _fly(
        tmp_path, "c", 3, "mission_time = 5.0\nseed = 2\n" + EAST + "[broadcast]\nreception = 0.5\n"
    )
    assert outcome.code == 0, outcome.report
    summaries = {f.agent: f.detail for f in record.faults if f.kind == "broadcast"}
    assert sorted(summaries) == ["e-01", "e-02", "e-03"]
    offered = sum(int(str(d["offered"])) for d in summaries.values())
    heard = sum(int(str(d["heard"])) for d in summaries.values())
    lo, hi = _binomial_99(offered, 0.5)
    assert offered >= 15 and lo <= heard <= hi, summaries
    assert "broadcast: e-01 heard" in outcome.report
    assert "broadcast reception e-02: heard" in format_summary(analyze_log(record.path))


def test_only_signed_fault_records_are_believed(tmp_path: Path) -> None:
    """With a swarm key, a forged "mission start" (or "crash") record on the LAN is dropped: it
    would start an agent process's faults early, or excuse an agent the operator should wait for."""
    from antalate_lcm.msgs import payload_t
    from antalate_lcm.runtime.fault_processes import read_record
    from antalate_lcm.wire.security import generate_key
    from antalate_lcm.wire.topics import FAULT_CHANNEL, FAULT_CONTENT_TYPE

    config = load_config(
        _write(tmp_path / "k.toml", CONFIG + f'[security]\nswarm_key = "{generate_key()}"\n')
    )
    node = Node(
        NodeSettings.from_config(config, agent="faults-0of2"), Context(Buses({"lan": "memq://"}), Executor())
    )
    record = {"agent": "operator", "kind": "mission", "event": "start", "at": 0.0}

    def message(seq: int, content_type: str = FAULT_CONTENT_TYPE, data: bytes | None = None) -> payload_t:
        msg = payload_t()
        msg.content_type = content_type
        msg.data = data if data is not None else json.dumps(record).encode()
        msg.size = len(msg.data)
        msg.header.agent, msg.header.seq = "faults", seq
        msg.header.utime = int(time.time() * 1e6)
        return msg

    forged = message(1)
    assert read_record(node, payload_t.decode(forged.encode()), FAULT_CHANNEL) is None
    signed = payload_t.decode(node.admission.seal(message(2)))
    assert read_record(node, signed, FAULT_CHANNEL) == record
    other = payload_t.decode(node.admission.seal(message(3, content_type="text/plain")))
    assert read_record(node, other, FAULT_CHANNEL) is None
    garbage = payload_t.decode(node.admission.seal(message(4, data=b"{not json")))
    assert read_record(node, garbage, FAULT_CHANNEL) is None


def test_the_operators_process_acts_on_the_agent_processes_records(tmp_path: Path) -> None:
    """With the agents elsewhere, the operator's side reads their records: a crash (or a freeze for
    good) excuses the agent, a lost link cuts the operator's side until its end; a record that
    names no fault of the script, or the wrong kind, changes nothing."""
    from antalate_lcm.msgs import payload_t
    from antalate_lcm.runtime.fault_processes import FaultRelay
    from antalate_lcm.wire.topics import FAULT_CHANNEL, FAULT_CONTENT_TYPE

    config = load_config(_write(tmp_path / "swarm.toml", CONFIG))
    script = Script.model_validate(
        {
            "mission_time": 9.0,
            "fault": [
                {"kind": "link_loss", "agent": "e-02", "at": 1.0, "duration": 2.0},
                {"kind": "crash", "agent": "e-01", "at": 1.0},
                {"kind": "freeze", "agent": "e-03", "at": 1.0},
            ],
        }
    )
    excused: list[str] = []
    relay = FaultRelay(
        NodeSettings.from_config(config, agent="faults"),
        Context(Buses({"lan": "memq://"}), Executor()),
        script=script,
        gate=FaultGate(),
        bus="lan",
        excuse=excused.append,
    )

    def hear(**record: Any) -> None:
        msg = payload_t()
        msg.content_type = FAULT_CONTENT_TYPE
        msg.data = json.dumps(record).encode()
        msg.size = len(msg.data)
        relay._heard(FAULT_CHANNEL, msg)

    hear(agent="e-02", kind="link_loss", event="start", at=1.0, fault=0)
    assert relay.gate.link_lost("e-02") and excused == []  # it comes back: still waited for
    hear(agent="e-01", kind="crash", event="start", at=1.0, fault=1)
    hear(agent="e-03", kind="freeze", event="start", at=1.0, fault=2)
    assert excused == ["e-01", "e-03"]
    hear(agent="e-04", kind="crash", event="start", at=1.0, fault=7)  # no such fault
    hear(agent="e-04", kind="crash", event="start", at=1.0, fault=0)  # fault 0 is no crash
    hear(agent="e-04", kind="crash", event="start", at=1.0, fault="1")
    hear(agent="operator", kind="mission", event="start", at=0.0)
    assert excused == ["e-01", "e-03"]
    hear(agent="e-02", kind="link_loss", event="end", at=3.0, fault=0)
    assert not relay.gate.link_lost("e-02")
    assert relay.report() == [
        "fault: link_loss start e-02 at 1.0 s of the mission",
        "fault: crash start e-01 at 1.0 s of the mission",
        "fault: freeze start e-03 at 1.0 s of the mission",
        "fault: link_loss end e-02 at 3.0 s of the mission",
    ]


@pytest.mark.netns
def test_faults_across_processes(netns, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """4 agents over 2 processes (udpm multicast in a namespace, signed with a swarm key): each
    agent process injects the faults of its own agents, timed from the operator's record of the
    mission's start, and their records reach the log; the operator waits no more for the crashed
    agent (in the other process)."""

    from antalate_lcm.wire.security import generate_key
    from tests.harness.process import antalate_argv, child_env

    config = _write(tmp_path / "swarm.toml", UDPM_CONFIG + f'[security]\nswarm_key = "{generate_key()}"\n')
    script = _write(
        tmp_path / "s.toml",
        "mission_time = 5.0\nseed = 3\n"
        + EAST
        + '[[fault]]\nkind = "crash"\nagent = "e-01"\nat = 1.0\n'
        + '[[fault]]\nkind = "freeze"\nagent = "e-03"\nat = 1.0\nduration = 2.0\n'
        + '[[fault]]\nkind = "sensor"\nsensor = "position"\nmode = "bias"\noffset = [20.0, 0.0]\n'
        + 'agent = "e-04"\nat = 2.0\nduration = 2.0\n'
        + '[[fault]]\nkind = "freeze"\nagent = "e-02"\nat = 1.0\nprobability = 0.0\n',
    )
    log = tmp_path / "f.lcm"
    argv = antalate_argv("--log-level", "WARNING", "run", str(config), "--agents", "4", "--processes", "2")
    argv += ["--headless", "--script", str(script), "-o", str(log)]
    env = child_env()
    env["XDG_STATE_HOME"] = str(tmp_path / "state")  # the swarm key's replay memory
    flight = netns.run(argv, timeout=180, cwd=tmp_path, env=env)
    assert flight.returncode == 0, flight.stdout + flight.stderr
    assert "(lost to a fault of the script)" in flight.stdout and "fault: crash start e-01" in flight.stdout
    record = read_log(log)
    (mission,) = [f for f in record.faults if f.kind == "mission"]
    assert (mission.agent, mission.event) == ("operator", "start")
    got = sorted((f.agent, f.kind, f.event) for f in record.faults if f.kind != "mission")
    assert got == [
        ("e-01", "crash", "start"),
        ("e-02", "freeze", "spared"),
        ("e-03", "freeze", "end"),
        ("e-03", "freeze", "start"),
        ("e-04", "sensor", "end"),
        ("e-04", "sensor", "start"),
    ], got
    for f in record.faults:  # at the script's time after the operator's mission start
        if f.kind == "mission":
            continue
        due = float(str(f.detail["at"]))
        assert due - 0.05 <= f.t - mission.t <= due + 0.6, (f, mission)
    crash = _faults(record, "e-01", "crash")["start"]
    assert crash.t - 1.0 < record.agents["e-01"].last_heard <= crash.t + 0.1
    freeze = _faults(record, "e-03", "freeze")
    times = [s.t for s in record.agents["e-03"].telemetry]
    assert not [t for t in times if freeze["start"].t + 0.1 < t < freeze["end"].t - 0.1]
    bias = _faults(record, "e-04", "sensor")
    e4, e2 = _ne(record, "e-04"), _ne(record, "e-02")  # e-02 and e-04 fly east one above the other
    during = _gap(e4, e2, 1, bias["start"].t + 0.3, bias["end"].t - 0.3)
    before = _gap(e4, e2, 1, bias["start"].t - 1.0, bias["start"].t - 0.1)
    assert during - before == pytest.approx(20.0, abs=1.5)
    for agent in ("e-02", "e-03", "e-04"):
        assert record.agents[agent].mc_states[-1].state == "STANDBY"


@pytest.mark.netns
def test_lossy_broadcasts_across_processes(netns, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """With the agents over 2 processes (udpm multicast in a namespace) each process loses the
    broadcasts at its own agents, from the same per-agent streams, and reports what each heard."""

    from tests.harness.process import antalate_argv, child_env

    # the peer sensor hears the other process's agents on the LAN: no swarm key in a test namespace
    config = _write(tmp_path / "swarm.toml", UDPM_CONFIG + "[security]\ninsecure = true\n")
    script = _write(
        tmp_path / "s.toml", "mission_time = 5.0\nseed = 2\n" + EAST + "[broadcast]\nreception = 0.5\n"
    )
    argv = antalate_argv("--log-level", "WARNING", "run", str(config), "--agents", "4", "--processes", "2")
    argv += ["--headless", "--script", str(script)]
    argv += ["-o", str(tmp_path / "c.lcm")]
    flight = netns.run(argv, timeout=180, cwd=tmp_path, env=child_env())
    assert flight.returncode == 0, flight.stdout + flight.stderr
    assert "OK: 4 agent(s), all back in STANDBY" in flight.stdout
    lines = [line for line in flight.stderr.splitlines() if line.startswith("broadcast: ")]
    assert sorted(line.split()[1] for line in lines) == ["e-01", "e-02", "e-03", "e-04"], flight.stderr
    counts = [(int(line.split()[3]), int(line.split()[5])) for line in lines]  # heard, offered
    offered, heard = sum(o for _, o in counts), sum(h for h, _ in counts)
    lo, hi = _binomial_99(offered, 0.5)
    assert offered >= 20 and lo <= heard <= hi, lines
