"""MCAP files of a flight (docs/tools.md): JSON field by field with schemas from the .lcm files, the
LCM bytes on request, Foxglove's well-known messages, and ``analyze``/``plot`` reading them.

The files are read back with the ``mcap`` library (not antalate's reader) and checked by
``@mcap/core`` under node, the MCAP authors' TypeScript reader that Foxglove uses: the Go ``mcap``
CLI is on no registry this project reaches (not PyPI, not npm), so its ``doctor`` cannot run here.
"""

from __future__ import annotations

import base64
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jsonschema
import lcm
import pytest
from mcap.reader import make_reader

from antalate_lcm.apps.analysis import analyze_log, read_log
from antalate_lcm.cli import main
from antalate_lcm.msgs import (
    arbiter_status_t,
    behavior_state_t,
    direction_cmd_t,
    hlc_error_t,
    hlc_state_t,
    mc_state_t,
    operator_cmd_t,
    payload_t,
    peer_detection_t,
    peer_scan_t,
    telemetry_t,
    velocity_cmd_t,
)
from antalate_lcm.wire import lcm_json
from antalate_lcm.wire.topics import MESSAGE_TYPES
from tests.harness.synthetic_logs import LAT0, LON0, T0, LogWriter
from tests.tools.npm_tools import run_node

MCAP_CHECK = Path(__file__).parent.parent / "node" / "mcap_check.mjs"


def _header(msg: Any, agent: str, seq: int, mac: bytes = b"") -> Any:
    msg.header.utime = T0 + seq
    msg.header.agent = agent
    msg.header.seq = seq
    msg.header.mac = mac
    msg.header.mac_len = len(mac)
    return msg


def every_type_log(path: Path) -> Path:
    """One message of every antalate topic (all 12 message types, header_t in each), with the values
    that are easy to get wrong: signatures, arrays, bytes, negative numbers, non-finite floats,
    unicode; plus a foreign channel, LCM's self-test and a damaged message."""
    w = LogWriter()
    mac = bytes(range(32))
    m = _header(mc_state_t(), "a-1", 1, mac)
    m.state, m.last_command_seq, m.takeoff_altitude, m.reason = 3, -7, 12.5, "operator TAKEOFF ✓"
    w.add(0.0, "a-1/MC_STATE", m.encode())
    h = _header(hlc_state_t(), "a-1", 2)
    h.state, h.autopilot, h.reason = 4, "sim", "altitude reached"
    w.add(0.1, "a-1/HLC_STATE", h.encode())
    t = _header(telemetry_t(), "a-1", 3)
    t.lat, t.lon, t.alt, t.heading = LAT0 + 1e-4, LON0 - 2e-4, 5.25, 359.5
    t.vn, t.ve, t.vd, t.battery, t.armed, t.in_air, t.mode = 1.5, -0.25, 0.0, -1.0, True, True, "GUIDED"
    w.add(0.2, "a-1/TELEMETRY", t.encode())
    e = _header(hlc_error_t(), "a-1", 4)
    e.code, e.severity, e.text = 3, hlc_error_t.ERROR, "takeoff refused: battery 12%"
    w.add(0.3, "a-1/HLC_ERROR", e.encode())
    v = _header(velocity_cmd_t(), "a-1", 5)
    v.frame, v.vx, v.vy, v.vz, v.yaw_rate = velocity_cmd_t.NED, float("nan"), float("inf"), -float("inf"), 3.0
    w.add(0.4, "a-1/VELOCITY_CMD", v.encode())
    o = _header(operator_cmd_t(), "operator", 6, mac)
    o.command, o.target, o.altitude = operator_cmd_t.TAKEOFF, "a-1", 8.0
    w.add(0.5, "a-1/OPERATOR_CMD", o.encode())
    so = _header(operator_cmd_t(), "operator", 7, mac)
    so.command = operator_cmd_t.RTL
    w.add(0.55, "SWARM/OPERATOR_CMD", so.encode())
    d = _header(direction_cmd_t(), "operator", 8, mac)
    d.active, d.azimuth, d.speed, d.target = True, 80.0, 1.5, ""
    w.add(0.6, "SWARM/DIRECTION_CMD", d.encode())
    d2 = _header(direction_cmd_t(), "operator", 9, mac)
    d2.active, d2.azimuth, d2.speed, d2.target = True, 270.0, 0.5, "a-1"
    w.add(0.65, "a-1/DIRECTION_CMD", d2.encode())
    for channel, blob in (("a-1/OPERATOR_PAYLOAD", b"\x00\xff{}"), ("a-1/OPERATOR_FEEDBACK", b'{"ok":1}')):
        p = _header(payload_t(), "a-1", 10)
        p.content_type, p.data, p.size = "application/octet-stream", blob, len(blob)
        w.add(0.7, channel, p.encode())
    b = _header(behavior_state_t(), "a-1", 11)
    b.state = "SEARCH"
    w.add(0.8, "a-1/BEHAVIOR_STATE", b.encode())  # not a default channel: a foreign one for the reader
    a = _header(arbiter_status_t(), "a-1", 12)
    a.arbiter, a.state, a.active, a.n = "swarm", "MISSION", ["dovrat_swarm", "direction_follow"], 2
    a.failed, a.n_failed = ["video_capture: no camera"], 1
    w.add(0.9, "a-1/ARBITER/swarm", a.encode())
    pd = _header(peer_detection_t(), "a-1", 13)
    pd.detected, pd.count, pd.nearest_range, pd.nearest_bearing = True, 2, 4.5, -30.0
    w.add(1.0, "a-1/PEER_DETECTION", pd.encode())
    ps = _header(peer_scan_t(), "a-1", 14)
    ps.max_range, ps.fov, ps.has_velocity, ps.n = 20.0, 360.0, True, 2
    ps.range, ps.bearing, ps.elevation = [4.5, 12.25], [-30.0, 179.5], [0.0, -5.0]
    ps.rel_forward, ps.rel_right, ps.id = [0.5, -1.0], [0.0, 2.0], ["", "a-2 ✓"]
    w.add(1.05, "a-1/PEER_SCAN", ps.encode())
    w.add(1.1, "LCM_SELF_TEST", b"self test")
    w.add(1.2, "a-2/TELEMETRY", b"\x01\x02 not a telemetry_t")
    return w.write(path)


def lcm_events(path: Path) -> list[tuple[int, str, bytes]]:
    log = lcm.EventLog(str(path), "r")
    out = []
    while (event := log.read_next_event()) is not None:
        out.append((int(event.timestamp), str(event.channel), bytes(event.data)))
    log.close()
    return out


def mcap_messages(path: Path) -> list[tuple[Any, Any, Any]]:
    with path.open("rb") as f:
        return list(make_reader(f, validate_crcs=True).iter_messages(log_time_order=False))


def assert_same_fields(lcm_value: Any, json_value: Any, where: str) -> None:
    """An LCM object's attributes against the JSON, walked on the LCM side (the generated class's
    slots), so a field the JSON leaves out or renames fails here."""
    if hasattr(lcm_value, "__slots__"):
        assert isinstance(json_value, dict), where
        assert list(json_value) == list(lcm_value.__slots__), where
        for name in lcm_value.__slots__:
            assert_same_fields(getattr(lcm_value, name), json_value[name], f"{where}.{name}")
    elif isinstance(lcm_value, bytes):
        assert base64.b64decode(json_value) == lcm_value, where
    elif isinstance(lcm_value, (list, tuple)):  # liblcm decodes numeric arrays as tuples
        assert isinstance(json_value, list) and len(json_value) == len(lcm_value), where
        for i, (a, b) in enumerate(zip(lcm_value, json_value, strict=True)):
            assert_same_fields(a, b, f"{where}[{i}]")
    elif isinstance(lcm_value, float) and not math.isfinite(lcm_value):
        assert json_value == (
            "NaN" if math.isnan(lcm_value) else "Infinity" if lcm_value > 0 else "-Infinity"
        )
    else:
        assert json_value == lcm_value and type(json_value) is type(lcm_value), where


def check_against_lcm(lcm_path: Path, mcap_path: Path) -> set[str]:
    """Every antalate message of the LCM log is in the MCAP file, in order, with the same fields, at
    the same log time; returns the types seen."""
    originals: dict[str, list[tuple[int, bytes]]] = {}
    for utime, channel, data in lcm_events(lcm_path):
        originals.setdefault(channel, []).append((utime, data))
    seen: dict[str, int] = {}
    types = set()
    for schema, channel, message in mcap_messages(mcap_path):
        if channel.message_encoding != "json" or "lcm_channel" not in channel.metadata:
            continue
        lcm_channel, type_name = channel.metadata["lcm_channel"], channel.metadata["lcm_type"]
        assert schema.name == f"antalate_lcm.msgs.{type_name}" and schema.encoding == "jsonschema"
        k = seen[lcm_channel] = seen.get(lcm_channel, -1) + 1
        utime, data = originals[lcm_channel][k]
        original = MESSAGE_TYPES[type_name].decode(data)
        assert message.log_time == utime * 1000
        assert_same_fields(original, json.loads(message.data), f"{lcm_channel}#{k}")
        types.add(type_name)
    return types


def validate_all(mcap_path: Path) -> int:
    """Every JSON message against its channel's schema (JSON Schema 2020-12); returns how many."""
    validators: dict[int, Any] = {}
    n = 0
    for schema, channel, message in mcap_messages(mcap_path):
        if channel.message_encoding != "json":
            continue
        if schema.id not in validators:
            doc = json.loads(schema.data)
            jsonschema.Draft202012Validator.check_schema(doc)
            validators[schema.id] = jsonschema.Draft202012Validator(doc)
        validators[schema.id].validate(json.loads(message.data))
        n += 1
    return n


def test_every_type_round_trips_through_mcap(tmp_path: Path) -> None:
    src = every_type_log(tmp_path / "all.lcm")
    out = tmp_path / "all.mcap"
    assert main(["export", str(src), "-o", str(out)]) == 0
    types = check_against_lcm(src, out)
    # behavior_state_t has no default channel (a behavior names its own): the next test covers it
    assert types == set(MESSAGE_TYPES) - {"behavior_state_t"} and len(types) == len(MESSAGE_TYPES) - 1
    assert validate_all(out) > 12
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for schema, channel, message in mcap_messages(out):
        if schema is not None and schema.name.startswith("foxglove."):
            by_topic.setdefault(f"{schema.name} {channel.topic}", []).append(json.loads(message.data))
    assert set(by_topic) == {
        "foxglove.LocationFix a-1/location",
        "foxglove.SceneUpdate swarm/scene",
        "foxglove.Log swarm/log",
    }
    fix = by_topic["foxglove.LocationFix a-1/location"][0]
    assert (fix["latitude"], fix["longitude"], fix["altitude"]) == (LAT0 + 1e-4, LON0 - 2e-4, 5.25)
    entity = by_topic["foxglove.SceneUpdate swarm/scene"][0]["entities"][0]
    assert entity["id"] == "a-1" and entity["texts"][0]["text"] == "a-1 MISSION"
    assert by_topic["foxglove.Log swarm/log"][0]["level"] == 4  # hlc_error_t ERROR
    # the foreign channel and the damaged telemetry are left out of a JSON file, and said so
    assert not any(c.topic in ("a-1/BEHAVIOR_STATE", "a-2/TELEMETRY") for _, c, _ in mcap_messages(out))


def test_behavior_state_and_header_fields_by_schema() -> None:
    """behavior_state_t rides on channels a behavior names (no default template),
    so it is checked through the writer directly; header_t is the nested object of every schema."""
    b = _header(behavior_state_t(), "a-1", 1, b"\x01\x02")
    b.state = "SEARCH"
    json_obj = lcm_json.to_json(b)
    assert_same_fields(b, json_obj, "behavior_state_t")
    jsonschema.validate(json_obj, lcm_json.schema("behavior_state_t"))
    assert lcm_json.from_json("behavior_state_t", json_obj).encode() == b.encode()
    header_schema = lcm_json.schema("header_t")
    for name in lcm_json.structs():
        if name != "header_t":
            assert lcm_json.schema(name)["properties"]["header"] == header_schema
    assert len(lcm_json.structs()) == len(MESSAGE_TYPES) + 1  # with header_t
    # units and meanings from the .lcm comments reach the schema
    props = lcm_json.schema("telemetry_t")["properties"]
    assert "m/s" in props["vn"]["description"] and "percent" in props["battery"]["description"]
    assert "MISSION=3" in lcm_json.schema("mc_state_t")["properties"]["state"]["description"]


def test_raw_keeps_the_lcm_bytes_and_reads_back_as_the_log(tmp_path: Path) -> None:
    src = every_type_log(tmp_path / "all.lcm")
    out = tmp_path / "raw.mcap"
    assert main(["export", str(src), "-o", str(out), "--raw"]) == 0
    originals = [(u, c, d) for u, c, d in lcm_events(src)]
    raw = [
        (m.log_time // 1000, c.metadata["lcm_channel"], m.data)
        for _, c, m in mcap_messages(out)
        if c.message_encoding == "lcm"
    ]
    assert raw == originals  # every event, foreign and damaged ones too, byte for byte, MACs included
    # analyze reads the MCAP file as it reads the LCM log, from the raw channels or from the JSON
    plain = tmp_path / "plain.mcap"
    assert main(["export", str(src), "-o", str(plain)]) == 0
    want = read_log(src)
    for path in (out, plain):
        got = read_log(path)
        assert got.agents.keys() == want.agents.keys()
        assert got.agents["a-1"].telemetry == want.agents["a-1"].telemetry
        assert got.agents["a-1"].mc_states == want.agents["a-1"].mc_states
        assert got.directions == want.directions
    assert read_log(out).undecodable == want.undecodable == {"a-2/TELEMETRY": 1}
    # plot reads it too, and names its PNG after the MCAP file
    from tests.harness.synthetic_logs import square_swarm

    swarm = tmp_path / "swarm.mcap"
    assert main(["export", str(square_swarm().write(tmp_path / "swarm.lcm")), "-o", str(swarm)]) == 0
    assert main(["plot", str(swarm), "-q"]) == 0
    assert (tmp_path / "swarm.png").stat().st_size > 10_000
    assert analyze_log(swarm).to_json() == analyze_log(tmp_path / "swarm.lcm").to_json() | {
        "path": str(swarm)
    }


def test_bad_inputs_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = every_type_log(tmp_path / "all.lcm")
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"not a log at all")
    assert main(["export", str(junk), "-o", str(tmp_path / "x.mcap")]) == 2
    assert "not an LCM log file" in capsys.readouterr().err
    out = tmp_path / "all.mcap"
    out.write_bytes(b"keep me")
    assert main(["export", str(src)]) == 2
    assert "exists: pass --force" in capsys.readouterr().err and out.read_bytes() == b"keep me"
    assert main(["export", str(src), "-o", str(src), "--force"]) == 2
    assert "is the log itself" in capsys.readouterr().err
    assert main(["export", str(src), "--force"]) == 0
    # a recording cut short (no summary, half a chunk): what precedes the damage is read
    whole = out.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    record = read_log(cut)
    assert record.truncated and "not valid MCAP" in record.truncated
    assert main(["analyze", str(cut)]) == 0
    # a JSON message edited into something that is no message of its type is counted, not fatal
    from mcap.writer import Writer

    edited = tmp_path / "edited.mcap"
    with edited.open("wb") as f:
        raw_writer = Writer(f)
        raw_writer.start()
        sid = raw_writer.register_schema("antalate_lcm.msgs.telemetry_t", "jsonschema", b"{}")
        cid = raw_writer.register_channel(
            "a-1/TELEMETRY", "json", sid, {"lcm_channel": "a-1/TELEMETRY", "lcm_type": "telemetry_t"}
        )
        raw_writer.add_message(cid, T0 * 1000, b'{"header": 5}', T0 * 1000)
        raw_writer.add_message(cid, T0 * 1000 + 1, b"{not json", T0 * 1000)
        t = _header(telemetry_t(), "a-1", 1)
        raw_writer.add_message(cid, T0 * 1000 + 2, json.dumps(lcm_json.to_json(t)).encode(), T0 * 1000)
        raw_writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish has no annotation
    record = read_log(edited)
    assert record.undecodable == {"a-1/TELEMETRY": 2} and len(record.agents["a-1"].telemetry) == 1


def test_mcap_core_reads_every_record(tmp_path: Path) -> None:
    """@mcap/core (TypeScript, the reader Foxglove uses) reads the file: CRCs, summary, indexes."""
    src = every_type_log(tmp_path / "all.lcm")
    out = tmp_path / "all.mcap"
    assert main(["export", str(src), "-o", str(out), "--raw"]) == 0
    done = run_node(MCAP_CHECK, str(out))
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    n = len(mcap_messages(out))
    assert report["stream"]["done"] and report["stream"]["messages"] == n
    assert report["stream"]["jsonErrors"] == 0
    assert report["indexed"]["messages"] == report["indexed"]["statisticsMessageCount"] == n


@pytest.mark.netns
def test_a_flight_recorded_live_and_exported(netns, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A demo flight (3 simulated agents, signed operator commands, behaviors) recorded by lcm-logger
    and by ``antalate log -o flight.mcap`` at once; the export of the LCM log matches it field by
    field, every message of both files validates against its schema, analyze reads both alike, and
    @mcap/core reads both."""
    from antalate_lcm.runtime.cli import native_lcm_tool
    from tests.conftest import MCAST_URL
    from tests.harness.process import stop_process

    cfg = tmp_path / "rec.toml"
    cfg.write_text(f'[agent]\nname = "rec"\n[buses]\nlan = "{MCAST_URL}"\n')
    lcm_path, live = tmp_path / "flight.lcm", tmp_path / "live.mcap"
    logger = netns.popen(
        [native_lcm_tool("lcm-logger"), f"--lcm-url={MCAST_URL}", str(lcm_path)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    recorder = netns.antalate("log", str(cfg), "-o", str(live), "--raw", stdout=subprocess.PIPE)
    assert recorder.stdout is not None and "(MCAP)" in recorder.stdout.readline()
    time.sleep(0.5)
    demo = netns.run(
        [
            sys.executable,
            "-m",
            "antalate_lcm.cli",
            "demo",
            "--headless",
            "--agents",
            "3",
            "--mission-time",
            "2",
        ],
        timeout=90,
    )
    assert demo.returncode == 0, demo.stdout + demo.stderr
    time.sleep(0.5)
    assert stop_process(logger) in (0, -15)
    assert stop_process(recorder) == 0
    exported = tmp_path / "flight.mcap"
    assert main(["export", str(lcm_path), "-o", str(exported)]) == 0
    types = check_against_lcm(lcm_path, exported)
    assert {"telemetry_t", "mc_state_t", "hlc_state_t", "operator_cmd_t", "arbiter_status_t"} <= types
    for path in (exported, live):
        assert validate_all(path) > 500
        done = run_node(MCAP_CHECK, str(path))
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout)["indexed"]["messages"] == len(mcap_messages(path))
    want, got = analyze_log(lcm_path), analyze_log(live)
    assert len(want.agents) == len(got.agents) == 3
    # the two loggers heard the same flight: the same agents went through the same MC states
    for name in want.agents:
        states = [s.state for s in read_log(lcm_path).agents[name].mc_states]
        assert [s.state for s in read_log(live).agents[name].mc_states] == states
        assert "MISSION" in states


def test_without_the_mcap_extra_the_commands_say_what_to_install(tmp_path: Path) -> None:
    from antalate_lcm.core.mcap_log import MCAP_MISSING
    from tests.architecture.test_optional_extras import antalate_without

    src = every_type_log(tmp_path / "all.lcm")
    proc = antalate_without("mcap", "export", str(src), "-o", str(tmp_path / "x.mcap"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and err.strip() == f"antalate: {MCAP_MISSING}"
    mcap_file = tmp_path / "all.mcap"
    assert main(["export", str(src), "-o", str(mcap_file)]) == 0
    proc = antalate_without("mcap", "analyze", str(mcap_file))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and err.strip() == f"antalate: {MCAP_MISSING}"
