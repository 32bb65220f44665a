"""``antalate mavlink-gcs`` (docs/tools.md): every agent a MAVLink vehicle, seen by MAVProxy (from PyPI, a
ground station no one here wrote); its TAKEOFF refused, then, with ``--commands``, flying the swarm
through signed operator commands. The mapping itself (``gcs.view``) is checked without sockets."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.apps.gcs.view import MC_MODES, GcsRefusal, GcsView, OperatorRequest
from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t, telemetry_t
from antalate_lcm.wire.security import generate_key
from antalate_lcm.wire.vocabulary import Command, HlcState, McState
from tests.conftest import MCAST_URL, Probe
from tests.harness.agents import agent_config
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.process import child_env, stop_process

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
AGENTS = 5


# ----------------------------------------------------------------------------- the mapping, pure
def _telemetry(**fields: Any) -> telemetry_t:
    t = telemetry_t()
    t.lat, t.lon, t.alt, t.heading, t.battery, t.armed, t.in_air = 32.5, 35.25, 12.5, 90.0, 73.0, True, True
    t.vn, t.ve, t.vd = 3.0, 4.0, -1.0
    for k, v in fields.items():
        setattr(t, k, v)
    return t


def test_an_agent_becomes_a_vehicle_with_its_own_system_id() -> None:
    view = GcsView(sysid_base=101)
    out = view.on_message("a", _telemetry(), 0.0, 1234)
    assert [(s, m.get_type()) for s, m in out] == [(101, "GLOBAL_POSITION_INT"), (101, "VFR_HUD")]
    pos, hud = out[0][1], out[1][1]
    assert (pos.lat, pos.lon, pos.relative_alt, pos.hdg) == (325_000_000, 352_500_000, 12_500, 9000)
    assert (pos.vx, pos.vy, pos.vz, pos.time_boot_ms) == (300, 400, -100, 1234)
    assert (hud.groundspeed, hud.heading, hud.climb) == (5.0, 90, 1.0)
    view.on_message("b", _telemetry(), 0.0, 0)
    assert view.vehicles["b"].sysid == 102
    m = mc_state_t()
    m.state, m.reason = McState.MISSION, "HLC airborne"
    ((sysid, text),) = view.on_message("a", m, 0.5, 0)
    assert sysid == 101 and text.text == "MC MISSION HLC airborne"
    assert view.on_message("a", m, 0.6, 0) == []  # a state republished unchanged says nothing
    h = hlc_state_t()
    h.state, h.autopilot = HlcState.AIRBORNE, "sim"
    view.on_message("a", h, 0.6, 0)
    beats = dict((s, m) for s, m in view.tick(1.0) if m.get_type() == "HEARTBEAT")
    assert set(beats) == {101, 102}
    beat = beats[101]
    assert mavutil.mode_mapping_acm[beat.custom_mode] == MC_MODES[McState.MISSION] == "AUTO"
    assert beat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED and beat.system_status == mav.MAV_STATE_ACTIVE
    assert beat.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA and beat.type == mav.MAV_TYPE_QUADROTOR
    status = next(m for s, m in view.tick(1.0) if s == 101 and m.get_type() == "SYS_STATUS")
    assert status.battery_remaining == 73
    e = hlc_error_t()
    e.code, e.severity, e.text = (
        3,
        hlc_error_t.CRITICAL,
        "takeoff refused: battery 12% is below the 20% minimum",
    )
    ((_, text),) = view.on_message("a", e, 1.1, 0)
    assert text.severity == mav.MAV_SEVERITY_CRITICAL and len(text.text) == 50  # STATUSTEXT's 50 chars
    # silent for longer than stale_after: no more heartbeats, the GCS shows the link lost
    assert {s for s, _ in view.tick(4.2)} == set()


def test_broken_telemetry_and_critical_states() -> None:
    view = GcsView()
    t = _telemetry(lat=math.nan, lon=math.inf, alt=-math.inf, heading=math.nan, vn=math.nan, battery=math.nan)
    pos, hud = (m for _, m in view.on_message("a", t, 0.0, 0))
    assert (pos.lat, pos.lon, pos.alt, pos.vx, pos.hdg) == (0, 0, 0, 0, 0xFFFF)
    assert (hud.groundspeed, hud.alt) == (0.0, 0.0)
    encoder = mav.MAVLink(_Sink())  # they pack: no NaN reached an integer field
    encoder.send(pos)
    encoder.send(hud)
    m = mc_state_t()
    m.state = McState.HLC_LOST
    view.on_message("a", m, 0.1, 0)
    beat, status = (m for _, m in view.tick(0.2))
    assert beat.system_status == mav.MAV_STATE_CRITICAL and status.battery_remaining == -1
    with pytest.raises(ValueError):
        GcsView(sysid_base=0)
    full = GcsView(sysid_base=254)
    for name in ("a", "b", "c"):
        full.on_message(name, _telemetry(), 0.0, 0)
    assert set(full.vehicles) == {"a", "b"} and full.unplaced == {"c"}


class _Sink:
    def __init__(self) -> None:
        self.data = b""

    def write(self, buf: bytes) -> None:
        self.data += buf


def test_what_a_ground_station_command_means() -> None:
    view = GcsView(sysid_base=101, hide_autopilots=frozenset({"mavlink"}))
    for name in ("a", "b"):
        view.on_message(name, _telemetry(), 0.0, 0)
    takeoff = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 7.5)
    assert view.request(0, mav.MAV_CMD_NAV_TAKEOFF, takeoff, 0.1) == OperatorRequest(Command.TAKEOFF, "", 7.5)
    assert view.request(102, mav.MAV_CMD_NAV_LAND, (), 0.1) == OperatorRequest(Command.LAND, "b", 0.0)
    assert view.request(101, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, (), 0.1) == OperatorRequest(
        Command.RTL, "a", 0.0
    )
    rtl_mode = (1.0, float(mavutil.mode_mapping_byname(mav.MAV_TYPE_QUADROTOR)["RTL"]))
    assert view.request(101, mav.MAV_CMD_DO_SET_MODE, rtl_mode, 0.1) == OperatorRequest(Command.RTL, "a", 0.0)
    stabilize = (1.0, 0.0)
    assert isinstance(view.request(101, mav.MAV_CMD_DO_SET_MODE, stabilize, 0.1), GcsRefusal)
    for bad in (math.nan, -3.0, math.inf):
        refusal = view.request(101, mav.MAV_CMD_NAV_TAKEOFF, (*takeoff[:6], bad), 0.1)
        assert isinstance(refusal, GcsRefusal) and refusal.result == mav.MAV_RESULT_DENIED
    arm = view.request(101, mav.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), 0.1)
    assert isinstance(arm, GcsRefusal) and arm.result == mav.MAV_RESULT_UNSUPPORTED
    assert view.request(1, mav.MAV_CMD_NAV_TAKEOFF, takeoff, 0.1) is None  # a real autopilot's id: not ours
    # an agent flying a MAVLink autopilot, hidden: its own MAVLink reaches the GCS, not a second picture
    h = hlc_state_t()
    h.autopilot = "mavlink"
    view.on_message("b", h, 0.2, 0)
    assert view.request(102, mav.MAV_CMD_NAV_LAND, (), 0.3) is None
    assert {s for s, _ in view.tick(0.3)} == {101}


# ----------------------------------------------------------------------------- MAVProxy, end to end
class MavProxy:
    """MAVProxy as a user runs it, its console lines collected as they come."""

    def __init__(self, netns: Any, tmp_path: Path, port: int, *extra: str) -> None:
        self.lines: list[str] = []
        self.proc = netns.popen(
            [
                sys.executable,
                str(MAVPROXY),
                f"--master=udpout:127.0.0.1:{port}",
                "--nowait",
                "--default-modules=link,cmdlong,mode",
                f"--logfile={tmp_path / 'mav.tlog'}",
                *extra,
            ],
            cwd=tmp_path,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def matching(self, pattern: str) -> list[re.Match[str]]:
        return [m for line in list(self.lines) if (m := re.search(pattern, line))]

    def vehicles(self) -> set[int]:
        return {int(m.group(1)) for m in self.matching(r"Detected vehicle (\d+):1")}

    def stop(self) -> None:
        stop_process(self.proc, timeout=1)  # MAVProxy's input thread ignores SIGTERM: killed after 1 s


def _gcs(netns: Any, cfg: Path, *extra: str) -> tuple[subprocess.Popen[str], dict[str, int], list[str]]:
    proc = netns.antalate("mavlink-gcs", str(cfg), *extra, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    sysids: dict[str, int] = {}
    lines: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if m := re.match(r"agent (\S+) is MAVLink system (\d+)", line):
                sysids[m.group(1)] = int(m.group(2))

    threading.Thread(target=read, daemon=True).start()
    return proc, sysids, lines


@pytest.mark.netns
def test_mavproxy_sees_five_vehicles_and_flies_them_only_when_commands_are_on(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    if not MAVPROXY.exists():
        pytest.skip("MAVProxy is not installed (pip install MAVProxy: the dev extra has it)")
    key = generate_key()
    sim = tmp_path / "sim.toml"
    sim.write_text(tomli_w.dumps({**agent_config("sim"), "security": {"swarm_key": key}}))
    gcs_cfg = tmp_path / "gcs.toml"
    gcs_cfg.write_text(
        tomli_w.dumps({"agent": {"name": "gcs"}, "buses": {"lan": MCAST_URL}, "security": {"swarm_key": key}})
    )
    agents = netns.antalate(
        "agent", str(sim), "--agents", str(AGENTS), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    names = [f"sim-{i:02d}" for i in range(1, AGENTS + 1)]
    gcs, sysids, gcs_lines = _gcs(netns, gcs_cfg, "--port", "14551")
    (tmp_path / "off").mkdir()
    forwarded = netns.popen(
        [sys.executable, "-m", "tests.children.mavlink_listen", "14600", str(AGENTS), "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    mavproxy = MavProxy(netns, tmp_path / "off", 14551, "--out=udpout:127.0.0.1:14600")
    try:
        # ---- commands off: five vehicles, where the agents are; a TAKEOFF is refused
        assert wait_for(lambda: len(mavproxy.vehicles()) == AGENTS, timeout=30), mavproxy.lines[-20:]
        assert wait_for(lambda: len(sysids) == AGENTS, timeout=10)
        assert mavproxy.vehicles() == set(sysids.values()) == set(range(101, 101 + AGENTS))
        refused_at = probe.mark()
        mavproxy.send("vehicle 0")
        mavproxy.send("takeoff 5")
        assert wait_for(lambda: mavproxy.matching(r"COMMAND_ACK: NAV_TAKEOFF: DENIED"), timeout=15), (
            mavproxy.lines[-20:]
        )
        assert wait_for(lambda: mavproxy.matching(r"GCS commands are off"), timeout=5)
        # the positions MAVProxy received (and forwards on its --out, as to a second GCS) are the agents'
        heard = json.loads(forwarded.communicate(timeout=30)[0])
        assert set(heard) == {str(i) for i in sysids.values()}
        for name in names:
            # refused: two seconds of telemetry after the takeoff, every one on the ground, MC in STANDBY
            telemetry = f"{name}/TELEMETRY"

            def recorded(ch: str = telemetry) -> bool:
                return len(probe.history(ch, "telemetry_t", since=refused_at)) >= 20

            assert wait_for(recorded, timeout=15)
            since = probe.history(telemetry, "telemetry_t", since=refused_at)
            assert not any(t["in_air"] or t["armed"] for t in since), name
            states = {m["state"] for m in probe.history(f"{name}/MC_STATE", "mc_state_t", since=refused_at)}
            assert states == {int(McState.STANDBY)}, (name, states)
            t = since[-1]
            lat, lon = heard[str(sysids[name])]
            assert (lat, lon) == (round(t["lat"] * 1e7), round(t["lon"] * 1e7)), name
        # garbage at the endpoint is dropped; the server keeps serving
        netns.run([sys.executable, "-m", "tests.children.mavlink_garbage", "14551"], env=child_env())
        assert gcs.poll() is None
        assert stop_process(gcs) == 0
        summary = wait_for(
            lambda: next((x for x in gcs_lines if x.startswith("ground station:")), None), timeout=5
        )
        m = re.search(
            r"(\d+) command\(s\) for the swarm, 0 sent as operator commands, (\d+) refused; (\d+) unreadable",
            summary or "",
        )
        assert m and int(m.group(1)) == int(m.group(2)) >= 1 and int(m.group(3)) >= 1, summary
        mavproxy.stop()

        # ---- commands on: the same TAKEOFF flies every agent, by a signed operator command
        gcs, sysids, _ = _gcs(netns, gcs_cfg, "--port", "14551", "--commands")
        (tmp_path / "on").mkdir()
        mavproxy = MavProxy(netns, tmp_path / "on", 14551)
        assert wait_for(lambda: len(mavproxy.vehicles()) == AGENTS, timeout=30), mavproxy.lines[-20:]
        mark = probe.mark()
        mavproxy.send("vehicle 0")
        mavproxy.send("takeoff 4")
        assert wait_for(lambda: mavproxy.matching(r"COMMAND_ACK: NAV_TAKEOFF: ACCEPTED"), timeout=15), (
            mavproxy.lines[-20:]
        )
        cmd = probe.wait("SWARM/OPERATOR_CMD", "operator_cmd_t", timeout=10, since=mark)
        assert cmd is not None and cmd["header"]["agent"] == "gcs" and cmd["altitude"] == 4.0
        assert cmd["header"]["mac_len"] == 32  # HMAC-SHA256 with the swarm key
        for name in names:
            assert probe.wait(
                f"{name}/MC_STATE", "mc_state_t", timeout=30, since=mark, state=int(McState.MISSION)
            ), name
            assert probe.wait(f"{name}/TELEMETRY", "telemetry_t", timeout=10, since=mark, in_air=True), name
        assert wait_for(lambda: mavproxy.matching(r"Mode AUTO"), timeout=10)  # MISSION shown as AUTO
    finally:
        mavproxy.stop()
        stop_process(gcs)
        stop_process(agents)


def test_refusals_before_anything_starts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from antalate_lcm.cli import main

    open_cfg = tmp_path / "open.toml"
    open_cfg.write_text(f'[agent]\nname = "gcs"\n[buses]\nlan = "{MCAST_URL}"\n')
    assert main(["mavlink-gcs", str(open_cfg), "--host", "0.0.0.0", "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "refusing to serve MAVLink on 0.0.0.0" in err and "--no-auth" in err
    assert main(["mavlink-gcs", str(open_cfg), "--gcs", "192.0.2.1:14550", "--commands"]) == 2
    assert "commands it" in capsys.readouterr().err  # beyond loopback with commands: says so
    assert main(["mavlink-gcs", str(open_cfg), "--port", "0", "--commands"]) == 2
    assert "--commands needs [security] swarm_key" in capsys.readouterr().err
    assert main(["mavlink-gcs", str(open_cfg), "--port", "0", "--sysid-base", "300"]) == 2
    assert "system id is 1..255" in capsys.readouterr().err
