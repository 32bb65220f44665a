"""The protocol emulators behave like the real vehicles, as seen through plain sockets and the real clients.

Tello: plain UDP sockets on 127.0.0.1 (random ports), plus one run of the real djitellopy in a private
network namespace pair (djitellopy binds 8889/8890 on all addresses, see tests/harness/netns.py).
MAVLink: the real pymavlink client over UDP (both directions of set-up) and TCP.
"""

from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from djitellopy import Tello
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests import REPO
from tests.emulators.mavlink_vehicle import COPTER_MODES, MavlinkVehicle
from tests.emulators.tello_emulator import TelloEmulator
from tests.harness.netns import NetnsPair, netns_pair_unavailable
from tests.vehicles.test_mavlink_adapter import FAST as ADAPTER_FAST

# -- Tello helpers ----------------------------------------------------------------------------------

#: djitellopy's ``Tello.TIME_BTW_COMMANDS``: what the emulator needs between commands, as a Tello does.
TIME_BTW_COMMANDS = Tello.TIME_BTW_COMMANDS


class TelloClient:
    """A bare SDK client: one UDP socket for commands, one for state (what djitellopy does, minus binding 8889)."""

    def __init__(self) -> None:
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.bind(("127.0.0.1", 0))
        self.state = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.state.bind(("127.0.0.1", 0))
        self.state_port = self.state.getsockname()[1]
        self.emulator: tuple[str, int] = ("127.0.0.1", 8889)
        self.spacing = TIME_BTW_COMMANDS
        self._quiet_since = -math.inf  # the last non-rc command sent or reply received

    def send(self, text: str) -> None:
        """One datagram; a non-rc one no sooner than `spacing` after the last command or reply (djitellopy)."""
        if text.split()[:1] != ["rc"]:
            time.sleep(max(0.0, self._quiet_since + self.spacing - time.monotonic()))
            self._quiet_since = time.monotonic()
        self.cmd.sendto(text.encode(), self.emulator)

    def ask(self, text: str, timeout: float = 3.0) -> str:
        self.send(text)
        self.cmd.settimeout(timeout)
        data, sender = self.cmd.recvfrom(1024)
        self._quiet_since = time.monotonic()
        assert sender == self.emulator, "replies must come from the address the emulator is bound to"
        return data.decode()

    def no_reply(self, text: str, wait: float = 0.2) -> bool:
        self.send(text)
        self.cmd.settimeout(wait)
        try:
            self.cmd.recvfrom(1024)
        except TimeoutError:
            return True
        self._quiet_since = time.monotonic()
        return False

    def state_packets(self, duration: float) -> list[str]:
        """Every state line received during ``duration`` seconds (after dropping what was queued)."""
        self.state.setblocking(False)
        try:
            while True:
                self.state.recv(2048)
        except BlockingIOError:
            pass
        lines: list[str] = []
        deadline = time.monotonic() + duration
        while (left := deadline - time.monotonic()) > 0:
            self.state.settimeout(left)
            try:
                lines.append(self.state.recv(2048).decode("ascii"))
            except TimeoutError:
                break
        return lines

    def close(self) -> None:
        self.cmd.close()
        self.state.close()


@pytest.fixture
def tello_client() -> Iterator[TelloClient]:
    client = TelloClient()
    yield client
    client.close()


@pytest.fixture
def tello(tello_client: TelloClient, request: pytest.FixtureRequest) -> Iterator[TelloEmulator]:
    """An emulator on a free 127.0.0.1 port whose state packets go to the client's state socket."""
    kwargs: dict[str, Any] = {"takeoff_time": 0.3, "land_speed": 2.0, "rotate_rate": 360.0}
    kwargs.update(getattr(request, "param", {}))
    with TelloEmulator("127.0.0.1", 0, state_port=tello_client.state_port, **kwargs) as emu:
        tello_client.emulator = emu.address
        yield emu


# -- Tello tests --------------------------------------------------------------------------------------


def test_tello_text_protocol(tello: TelloEmulator, tello_client: TelloClient) -> None:
    assert tello_client.ask("battery?") == "error"  # not in SDK mode yet
    assert tello_client.ask("command") == "ok"
    assert tello_client.ask("sdk?") == "20"
    assert tello_client.ask("sn?") == tello.serial
    assert tello_client.ask("battery?") == "100"
    assert tello_client.ask("speed?") == "100"
    assert tello_client.ask("wifi?") == "90"
    assert tello_client.ask("height?") == "0dm"
    assert tello_client.ask("time?") == "0s"
    assert tello_client.ask("forward 50") == "error Motor stop"
    assert tello_client.ask("forward 5") == "out of range"
    assert tello_client.ask("jump") == "unknown command: jump"
    assert tello_client.ask("streamon") == "ok" and tello.snapshot().stream_on
    assert tello_client.ask("streamoff") == "ok"
    assert tello_client.ask("takeoff") == "ok"  # answered once the climb is over
    snap = tello.snapshot()
    assert snap.flying and snap.z == pytest.approx(0.8)
    assert tello_client.ask("height?") == "8dm"
    assert tello_client.ask("takeoff") == "error"
    assert tello_client.ask("up 40") == "ok"
    assert tello.snapshot().z == pytest.approx(1.2)
    assert tello_client.ask("cw 90") == "ok"
    assert tello.snapshot().yaw == pytest.approx(90)
    assert tello_client.ask("forward 50") == "ok"  # facing +y now
    assert (tello.snapshot().x, tello.snapshot().y) == pytest.approx((0.0, 0.5), abs=1e-6)
    assert tello_client.ask("go 0 50 0 100") == "ok"  # body y is left: facing +y, left is +x
    assert tello.snapshot().x == pytest.approx(0.5, abs=1e-6)
    assert tello_client.ask("go 10 10 10 50") == "out of range"
    assert tello_client.ask("speed 50") == "ok" and tello_client.ask("speed?") == "50"
    assert tello_client.ask("keepalive") == "ok"
    assert tello_client.ask("stop") == "ok"
    assert tello_client.no_reply("emergency")
    snap = tello.snapshot()
    assert not snap.flying and snap.z == 0.0
    texts = tello.command_texts()
    assert texts[:2] == ["battery?", "command"] and texts[-1] == "emergency"
    assert all(dest == tello_client.cmd.getsockname() for _, dest in tello.replies)


def test_tello_state_packets(tello: TelloEmulator, tello_client: TelloClient) -> None:
    assert tello_client.state_packets(0.2) == []  # nothing before SDK mode
    assert tello_client.ask("command") == "ok"
    lines = tello_client.state_packets(1.0)
    assert 8 <= len(lines) <= 12, f"{len(lines)} state packets in 1 s, expected ~10"
    line = lines[-1]
    assert line.startswith("mid:-1;x:0;y:0;z:0;mpry:0,0,0;pitch:") and line.endswith(";\r\n")
    state = Tello.parse_state(line)  # djitellopy's own parser: every field converts
    for key in ("pitch", "roll", "yaw", "vgx", "vgy", "vgz", "templ", "temph", "tof", "h", "bat", "time"):
        assert isinstance(state[key], int), key
    for key in ("baro", "agx", "agy", "agz"):
        assert isinstance(state[key], float), key
    assert state["bat"] == 100 and state["h"] == 0 and state["agz"] == pytest.approx(-1000)

    tello.set_battery(42)
    assert Tello.parse_state(tello_client.state_packets(0.25)[-1])["bat"] == 42
    tello.stop_state()
    assert tello_client.state_packets(0.3) == []
    tello.resume_state()
    assert len(tello_client.state_packets(0.3)) >= 2


@pytest.mark.parametrize("tello", [{"max_speed": 1.0, "max_yaw_rate": 100.0}], indirect=True)
def test_tello_rc_moves_without_reply(tello: TelloEmulator, tello_client: TelloClient) -> None:
    assert tello_client.ask("command") == "ok"
    assert tello_client.ask("takeoff") == "ok"
    assert tello_client.no_reply("rc 0 100 0 0")  # rc is never answered
    assert tello.wait_until(lambda s: s.x > 0.4, timeout=3)
    state = Tello.parse_state(tello_client.state_packets(0.25)[-1])
    assert (
        state["vgx"] in (9, 10) and state["vgy"] == 0
    )  # full stick = 1 m/s = 10 dm/s along the initial heading
    assert tello_client.no_reply("rc 50 0 -20 100")
    assert tello.wait_until(lambda s: s.yaw > 45, timeout=2)
    assert tello.snapshot().vz < 0
    tello_client.send("rc 0 0 0 0")
    assert tello.wait_until(lambda s: abs(s.vx) + abs(s.vy) < 0.02, timeout=2)
    assert tello_client.no_reply("rc 1 2 3")  # malformed rc: ignored, still no reply
    assert tello.snapshot().rc == (0, 0, 0, 0)
    assert tello_client.ask("land") == "ok"
    assert not tello.snapshot().flying


@pytest.mark.parametrize("tello", [{"auto_land_timeout": 0.6}], indirect=True)
def test_tello_auto_lands_without_commands(tello: TelloEmulator, tello_client: TelloClient) -> None:
    assert tello_client.ask("command") == "ok"
    assert tello_client.ask("takeoff") == "ok"
    for _ in range(8):  # commands keep it up (rc counts)
        tello_client.send("rc 0 0 0 0")
        time.sleep(0.1)
    assert tello.snapshot().flying
    assert tello.wait_until(lambda s: not s.flying, timeout=3)
    assert tello.snapshot().z == 0.0


def test_tello_faults(tello: TelloEmulator, tello_client: TelloClient) -> None:
    assert tello_client.ask("command") == "ok"
    tello.refuse_takeoff = True
    assert tello_client.ask("takeoff") == "error"
    tello.refuse_takeoff = False
    tello.set_battery(8)
    assert tello_client.ask("takeoff") == "error"  # below min_takeoff_battery
    tello.set_battery(50)
    assert tello_client.ask("takeoff") == "ok"
    tello.set_battery(3)  # at auto_land_battery it lands by itself
    assert tello.wait_until(lambda s: not s.flying, timeout=3)


def test_tello_cli(tello_client: TelloClient) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.emulators.tello_emulator",
            "--port",
            "0",
            "--state-target",
            f"127.0.0.1:{tello_client.state_port}",
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline().split()
        assert ready[0] == "READY", ready
        tello_client.emulator = (ready[1], int(ready[2]))
        assert tello_client.ask("command") == "ok"
        assert tello_client.state_packets(0.3)
        proc.send_signal(signal.SIGTERM)
        out, _err = proc.communicate(timeout=5)
        final = json.loads(out.strip().splitlines()[-1])
        assert final["sdk_mode"] and final["commands"] == ["command"]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.netns
def test_real_djitellopy_against_emulator() -> None:
    reason = netns_pair_unavailable()
    if reason:
        pytest.skip(reason)
    with (
        NetnsPair() as net,
        # no spacing rule here: djitellopy sends at once when an answer is already queued at its first
        # look, which a loaded machine causes against an emulator that answers within a millisecond
        # (tello_emulator.py's docstring); the rule is tested against antalate's adapter, which spaces
        TelloEmulator(
            sock=net.udp_socket("a", (net.addr_a, 8889)), takeoff_time=0.5, command_spacing=0.0
        ) as emu,
    ):
        done = net.run("b", [sys.executable, "-m", "tests.children.djitellopy_flight"], timeout=60)
        # what the emulator heard and ignored (too soon after the last command), when djitellopy gave up
        heard = [(round(c.t, 3), c.text) for c in emu.commands]
        assert done.returncode == 0, (done.stderr, heard, [(round(c.t, 3), c.text) for c in emu.ignored])
        out = json.loads(done.stdout.strip().splitlines()[-1])
        snap = emu.snapshot()
    assert out["battery"] == 100 and out["battery_q"] == 100 and out["sdk"] == "20"
    assert out["h_flying"] == 80 and out["h_landed"] == 0
    assert out["vgx"] >= 3  # dm/s, forward along the initial heading
    assert not snap.flying and snap.x > 0.2 and snap.client == (net.addr_b, 8889)
    texts = [c.text for c in emu.commands]
    assert texts[:2] == ["command", "sdk?"] and "takeoff" in texts and texts[-1] == "land"
    assert sum(t.startswith("rc ") for t in texts) >= 8


# -- MAVLink helpers --------------------------------------------------------------------------------------


def recv(
    conn: Any, mtype: str | list[str], pred: Callable[[Any], bool] = lambda m: True, timeout: float = 5.0
) -> Any:
    """The next message of ``mtype`` satisfying ``pred``, or None after ``timeout``."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = conn.recv_match(type=mtype, blocking=True, timeout=min(left, 0.2))
        if msg is not None and pred(msg):
            return msg
    return None


def drain(conn: Any) -> None:
    """Drop what is already queued, so the next ``recv`` sees only what the vehicle sends from now on."""
    while conn.recv_match(blocking=False) is not None:
        pass


def command(conn: Any, cmd: int, *params: float, timeout: float = 2.0) -> int | None:
    """Send a COMMAND_LONG and return the COMMAND_ACK result (None: no ACK)."""
    p = [*params, *[0.0] * (7 - len(params))]
    conn.mav.command_long_send(1, 1, cmd, 0, *p)
    ack = recv(conn, "COMMAND_ACK", lambda m: m.command == cmd, timeout=timeout)
    return None if ack is None else ack.result


def set_mode(conn: Any, mode: str) -> int | None:
    return command(conn, mav2.MAV_CMD_DO_SET_MODE, mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, COPTER_MODES[mode])


def arm(conn: Any) -> int | None:
    return command(conn, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1)


def velocity(
    conn: Any, vn: float, ve: float, vd: float, yaw_rate: float = 0.0, frame: int = mav2.MAV_FRAME_LOCAL_NED
) -> None:
    mask = 0b0000_0101_1100_0111  # use vx vy vz and yaw rate
    conn.mav.set_position_target_local_ned_send(
        0, 1, 1, frame, mask, 0, 0, 0, vn, ve, vd, 0, 0, 0, 0, yaw_rate
    )


def connect_udp(vehicle: MavlinkVehicle) -> Any:
    conn = mavutil.mavlink_connection(vehicle.udp_url, source_system=255)
    conn.mav.heartbeat_send(
        mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0
    )  # so it learns our address
    return conn


# The adapter tests' brisk copter (every flight takes a few seconds), heartbeats at 4 Hz and the two
# streams the tests below read at 5 Hz.
FAST: dict[str, Any] = {
    **ADAPTER_FAST,
    "heartbeat_rate": 4.0,
    "stream_rates": {"EXTENDED_SYS_STATE": 5.0, "SYS_STATUS": 5.0},
}


@pytest.fixture
def vehicle(request: pytest.FixtureRequest) -> Iterator[MavlinkVehicle]:
    with MavlinkVehicle("127.0.0.1", 0, **{**FAST, **getattr(request, "param", {})}) as v:
        yield v


@pytest.fixture
def gcs(vehicle: MavlinkVehicle) -> Iterator[Any]:
    """A pymavlink client on the vehicle's UDP port, once the vehicle is ready to arm."""
    conn = connect_udp(vehicle)
    try:
        assert conn.wait_heartbeat(timeout=3) is not None
        assert vehicle.wait_until(lambda s: s.ekf_position_ok, timeout=3)
        yield conn
    finally:
        conn.close()


def fly_to(conn: Any, vehicle: MavlinkVehicle, alt: float) -> None:
    assert set_mode(conn, "GUIDED") == mav2.MAV_RESULT_ACCEPTED
    assert arm(conn) == mav2.MAV_RESULT_ACCEPTED
    assert command(conn, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt) == mav2.MAV_RESULT_ACCEPTED
    assert vehicle.wait_until(
        lambda s: s.alt > alt - 0.1 and s.guided_submode == "hover", timeout=alt / 2 + 3
    )


# -- MAVLink tests ----------------------------------------------------------------------------------------


def test_mavlink_boot_mode_revert_and_arming_gate() -> None:
    client = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    try:
        port = client.port.getsockname()[1]
        # phases long enough for a loaded machine to see each one (BOOT then CALIBRATING each half of
        # boot_delay, then no position until ekf/gps_delay); 0.6/1.3 s were missed at load 7
        params: dict[str, Any] = {
            "boot_delay": 3.0,
            "ekf_delay": 6.0,
            "gps_delay": 6.0,
            "heartbeat_rate": 8.0,
            "stream_rates": {"GPS_RAW_INT": 5.0, "EKF_STATUS_REPORT": 5.0},
        }
        with MavlinkVehicle("127.0.0.1", 0, udp_target=("127.0.0.1", port), **params) as vehicle:
            first = client.wait_heartbeat(timeout=2)
            assert first is not None and first.system_status == mav2.MAV_STATE_BOOT
            assert (
                first.type == mav2.MAV_TYPE_QUADROTOR and first.autopilot == mav2.MAV_AUTOPILOT_ARDUPILOTMEGA
            )
            assert first.get_srcSystem() == 1 and first.get_srcComponent() == mav2.MAV_COMP_ID_AUTOPILOT1
            assert first.get_header().mlen and client.WIRE_PROTOCOL_VERSION == "2.0"
            assert arm(client) == mav2.MAV_RESULT_FAILED  # still booting
            # a mode set during boot is accepted ... and silently reverted when boot ends
            assert set_mode(client, "GUIDED") == mav2.MAV_RESULT_ACCEPTED
            assert recv(client, "HEARTBEAT", lambda m: m.custom_mode == COPTER_MODES["GUIDED"], timeout=1)
            assert recv(
                client, "HEARTBEAT", lambda m: m.system_status == mav2.MAV_STATE_CALIBRATING, timeout=3
            )
            hb = recv(client, "HEARTBEAT", lambda m: m.system_status == mav2.MAV_STATE_STANDBY, timeout=4)
            assert hb is not None and hb.custom_mode == COPTER_MODES["STABILIZE"]
            # booted, but no GPS fix / EKF position yet
            gps = recv(client, "GPS_RAW_INT")
            assert gps is not None and gps.fix_type == 0
            ekf = recv(client, "EKF_STATUS_REPORT")
            assert ekf is not None and not ekf.flags & mav2.EKF_POS_HORIZ_ABS
            assert arm(client) == mav2.MAV_RESULT_FAILED
            # the reason arrives as STATUSTEXT just before the ACK (mavutil keeps the last of each type)
            assert client.messages["STATUSTEXT"].text == "PreArm: GPS 1: Bad fix"
            assert set_mode(client, "GUIDED") == mav2.MAV_RESULT_FAILED  # needs a position now
            assert recv(client, "GPS_RAW_INT", lambda m: m.fix_type == 3, timeout=6)
            assert recv(client, "EKF_STATUS_REPORT", lambda m: m.flags & mav2.EKF_POS_HORIZ_ABS, timeout=6)
            assert recv(client, "GLOBAL_POSITION_INT", lambda m: m.lat != 0, timeout=2)
            assert arm(client) == mav2.MAV_RESULT_ACCEPTED
            hb = recv(client, "HEARTBEAT", lambda m: m.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED, timeout=1)
            assert hb is not None and hb.system_status == mav2.MAV_STATE_ACTIVE
            assert vehicle.snapshot().armed
    finally:
        client.close()


@pytest.mark.parametrize("vehicle", [{"guided_timeout": 0.4}], indirect=True)
def test_mavlink_guided_takeoff_velocity_land(vehicle: MavlinkVehicle, gcs: Any) -> None:
    assert arm(gcs) == mav2.MAV_RESULT_ACCEPTED  # STABILIZE can arm ...
    assert (
        command(gcs, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3) == mav2.MAV_RESULT_FAILED
    )  # ... not take off
    assert set_mode(gcs, "GUIDED") == mav2.MAV_RESULT_ACCEPTED
    assert command(gcs, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2) == mav2.MAV_RESULT_ACCEPTED
    assert recv(
        gcs, "EXTENDED_SYS_STATE", lambda m: m.landed_state == mav2.MAV_LANDED_STATE_TAKEOFF, timeout=2
    )
    pos = recv(gcs, "GLOBAL_POSITION_INT", lambda m: m.relative_alt > 1890, timeout=4)
    assert pos is not None and pos.relative_alt < 2200
    assert recv(
        gcs, "EXTENDED_SYS_STATE", lambda m: m.landed_state == mav2.MAV_LANDED_STATE_IN_AIR, timeout=2
    )
    assert gcs.motors_armed()

    for _ in range(6):  # 3 m/s east for 0.6 s
        velocity(gcs, 0.0, 3.0, 0.0, yaw_rate=0.5)
        time.sleep(0.1)
    snap = vehicle.snapshot()
    assert snap.east > 1.0 and abs(snap.north) < 0.05 and snap.ve > 2.5 and snap.yaw > 10
    pos = recv(gcs, "GLOBAL_POSITION_INT", lambda m: m.vy > 100)
    assert pos is not None and pos.lon > round(snap.lon * 1e7) - 200 and pos.hdg > 0
    # no new target: ArduCopter stops after its guided timeout
    assert vehicle.wait_until(lambda s: abs(s.ve) < 0.05 and s.guided_submode == "hover", timeout=2.5)

    assert set_mode(gcs, "LAND") == mav2.MAV_RESULT_ACCEPTED
    assert recv(
        gcs, "EXTENDED_SYS_STATE", lambda m: m.landed_state == mav2.MAV_LANDED_STATE_LANDING, timeout=2
    )
    assert recv(gcs, "HEARTBEAT", lambda m: not m.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED, timeout=6)
    assert recv(
        gcs, "EXTENDED_SYS_STATE", lambda m: m.landed_state == mav2.MAV_LANDED_STATE_ON_GROUND, timeout=2
    )
    snap = vehicle.snapshot()
    assert snap.alt == 0.0 and not snap.armed and snap.mode == "LAND" and snap.east > 1.0


def test_mavlink_body_frame_velocity_and_rtl(vehicle: MavlinkVehicle, gcs: Any) -> None:
    fly_to(gcs, vehicle, 1.5)
    assert command(gcs, mav2.MAV_CMD_CONDITION_YAW, 90, 0, 1, 0) == mav2.MAV_RESULT_ACCEPTED
    assert vehicle.wait_until(lambda s: abs(s.yaw - 90) < 1, timeout=3)
    for _ in range(8):  # forward in the body frame = east when facing east
        velocity(gcs, 3.0, 0.0, 0.0, frame=mav2.MAV_FRAME_BODY_NED)
        time.sleep(0.1)
    snap = vehicle.snapshot()
    assert snap.east > 1.0 and abs(snap.north) < 0.1
    assert set_mode(gcs, "RTL") == mav2.MAV_RESULT_ACCEPTED
    assert vehicle.wait_until(lambda s: s.rtl_phase == "land", timeout=4)
    assert vehicle.wait_until(lambda s: not s.armed, timeout=5)
    snap = vehicle.snapshot()
    assert abs(snap.north) < 0.5 and abs(snap.east) < 0.5 and snap.alt == 0.0


@pytest.mark.parametrize("vehicle", [{"disarm_delay": 0.5}], indirect=True)
def test_mavlink_refusals_and_auto_disarm(vehicle: MavlinkVehicle, gcs: Any) -> None:
    vehicle.refuse_arm = True
    assert arm(gcs) == mav2.MAV_RESULT_FAILED
    assert "refuse_arm" in gcs.messages["STATUSTEXT"].text
    vehicle.refuse_arm = False
    assert set_mode(gcs, "LAND") == mav2.MAV_RESULT_ACCEPTED
    assert arm(gcs) == mav2.MAV_RESULT_FAILED  # LAND is not an arming mode
    assert set_mode(gcs, "AUTO") == mav2.MAV_RESULT_FAILED  # no mission
    assert set_mode(gcs, "GUIDED") == mav2.MAV_RESULT_ACCEPTED
    assert arm(gcs) == mav2.MAV_RESULT_ACCEPTED
    # armed but no takeoff: ArduCopter disarms itself after DISARM_DELAY
    assert recv(gcs, "HEARTBEAT", lambda m: not m.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED, timeout=2)
    assert command(gcs, 31999) == mav2.MAV_RESULT_UNSUPPORTED  # every COMMAND_LONG is acknowledged
    gcs.mav.set_mode_send(
        1, mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, COPTER_MODES["LOITER"]
    )  # the message form
    ack = recv(gcs, "COMMAND_ACK", lambda m: m.command == mav2.MAVLINK_MSG_ID_SET_MODE, timeout=2)
    assert ack is not None and ack.result == mav2.MAV_RESULT_ACCEPTED and vehicle.snapshot().mode == "LOITER"


def test_mavlink_pilot_override_and_battery(vehicle: MavlinkVehicle, gcs: Any) -> None:
    fly_to(gcs, vehicle, 1.5)
    acks_before = len(vehicle.acks)
    assert vehicle.pilot_switch_mode("LOITER")
    assert recv(gcs, "HEARTBEAT", lambda m: m.custom_mode == COPTER_MODES["LOITER"], timeout=1)
    assert len(vehicle.acks) == acks_before  # no COMMAND_ACK for a pilot's switch
    velocity(gcs, 2.0, 0.0, 0.0)  # ignored outside GUIDED
    time.sleep(0.5)
    assert abs(vehicle.snapshot().vn) < 0.05
    vehicle.set_battery(17)
    assert recv(gcs, "SYS_STATUS", lambda m: m.battery_remaining == 17, timeout=2)
    assert gcs.recv_match(type="SYS_STATUS", blocking=True, timeout=2).voltage_battery < 12600


def test_mavlink_streams_and_requests(vehicle: MavlinkVehicle, gcs: Any) -> None:
    gcs.mav.request_data_stream_send(1, 1, mav2.MAV_DATA_STREAM_ALL, 0, 0)  # stop every stream
    time.sleep(0.3)
    drain(gcs)
    assert recv(gcs, "GLOBAL_POSITION_INT", timeout=0.6) is None
    assert recv(gcs, "HEARTBEAT", timeout=1) is not None  # heartbeats are not a stream
    gcs.mav.request_data_stream_send(1, 1, mav2.MAV_DATA_STREAM_POSITION, 10, 1)
    assert recv(gcs, "GLOBAL_POSITION_INT", timeout=1) is not None
    assert command(gcs, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAVLINK_MSG_ID_ATTITUDE, 50_000) == 0
    start, count = time.monotonic(), 0
    while time.monotonic() - start < 0.5:
        if gcs.recv_match(type="ATTITUDE", blocking=True, timeout=0.1) is not None:
            count += 1
    assert 7 <= count <= 13, f"{count} ATTITUDE in 0.5 s at 20 Hz"
    assert command(gcs, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAVLINK_MSG_ID_ATTITUDE, -1) == 0
    assert command(gcs, mav2.MAV_CMD_REQUEST_MESSAGE, mav2.MAVLINK_MSG_ID_HOME_POSITION) == 0
    home = recv(gcs, "HOME_POSITION", timeout=1)
    assert home is not None and home.latitude == round(-35.363262 * 1e7)
    assert command(gcs, mav2.MAV_CMD_REQUEST_MESSAGE, mav2.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == 0
    assert recv(gcs, "AUTOPILOT_VERSION", timeout=1) is not None


def test_mavlink_link_loss(vehicle: MavlinkVehicle, gcs: Any) -> None:
    vehicle.stop_heartbeats()
    time.sleep(0.1)
    drain(gcs)
    assert gcs.recv_match(blocking=True, timeout=0.8) is None  # silence: no heartbeat, no telemetry
    assert command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=0.5) is None  # and nothing is heard
    assert not vehicle.snapshot().armed and not vehicle.snapshot().link_up
    vehicle.resume_heartbeats()
    assert recv(gcs, "HEARTBEAT", timeout=1.5) is not None


def test_mavlink_over_tcp_and_home_config() -> None:
    with MavlinkVehicle("127.0.0.1", None, 0, home_lat=47.397742, home_lon=8.545594, **FAST) as vehicle:
        conn = mavutil.mavlink_connection(vehicle.tcp_url, source_system=255)
        try:
            assert conn.wait_heartbeat(timeout=3) is not None
            pos = recv(conn, "GLOBAL_POSITION_INT", lambda m: m.lat != 0, timeout=3)
            assert pos is not None
            assert pos.lat == pytest.approx(473977420, abs=2) and pos.lon == pytest.approx(85455940, abs=2)
            assert set_mode(conn, "GUIDED") == mav2.MAV_RESULT_ACCEPTED
            assert arm(conn) == mav2.MAV_RESULT_ACCEPTED
            assert conn.flightmode == "GUIDED" or recv(
                conn, "HEARTBEAT", lambda m: m.custom_mode == 4, timeout=1
            )
        finally:
            conn.close()


def test_mavlink_cli() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.emulators.mavlink_vehicle", "--udp-port", "0", "--boot-delay", "0.1"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    conn = None
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline().split()
        assert ready and ready[0] == "READY", ready
        port = int(ready[1].removeprefix("udp="))
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        conn.mav.heartbeat_send(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert conn.wait_heartbeat(timeout=3) is not None
        proc.send_signal(signal.SIGTERM)
        out, _err = proc.communicate(timeout=5)
        assert json.loads(out.strip().splitlines()[-1])["mode"] == "STABILIZE"
    finally:
        if conn is not None:
            conn.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
