"""`MavlinkAdapter` against the ArduCopter-like emulator, through the real pymavlink, on 127.0.0.1.

Each test starts its own emulated copter with short boot/EKF/GPS delays and brisk kinematics so a
whole flight takes a few seconds; the adapter sees it exactly as it would see SITL (UDP both ways, TCP).
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from antalate_lcm.vehicles import AutopilotError, FlightMode, Frame, VehicleState, load_adapter
from antalate_lcm.vehicles.mavlink import DEFAULTS, VELOCITY_TYPE_MASK, MavlinkAdapter, Params
from tests.emulators.mavlink_vehicle import BRISK, MavlinkVehicle, VehicleSnapshot
from tests.harness.polling import wait_for

# The brisk copter (short delays, heartbeats at 10 Hz so mode confirmations are quick), landing at
# 2 m/s, turning at 180 deg/s and returning at the emulator's default 5 m/s.
FAST: dict[str, Any] = {**BRISK, "land_speed": 2.0, "yaw_rate_max": 180.0, "rtl_speed": 5.0}
AP: dict[str, Any] = {
    "stream_rate_hz": 20.0,
    "connect_timeout": 3.0,
    "ready_timeout": 5.0,
    "ack_timeout": 0.5,
    "mode_timeout": 2.0,
}


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def make_ap(connection: str, **params: Any) -> MavlinkAdapter:
    return MavlinkAdapter({"connection": connection, **AP, **params})


@pytest.fixture
def vehicle(request: pytest.FixtureRequest) -> Iterator[MavlinkVehicle]:
    with MavlinkVehicle("127.0.0.1", 0, 0, **{**FAST, **getattr(request, "param", {})}) as v:
        yield v


@pytest.fixture
def ap(vehicle: MavlinkVehicle, request: pytest.FixtureRequest) -> Iterator[MavlinkAdapter]:
    """An adapter connected to `vehicle` over UDP (``udpout``: the adapter's HEARTBEAT goes first)."""
    adapter = make_ap(vehicle.udp_url, **getattr(request, "param", {}))
    adapter.connect()
    try:
        yield adapter
    finally:
        adapter.close()


def state_until(
    ap: MavlinkAdapter, predicate: Callable[[VehicleState], bool], timeout: float
) -> VehicleState:
    s = wait_for(lambda: (lambda st: st if predicate(st) else None)(ap.state()), timeout)
    assert s is not None, f"state never matched; last {ap.state()}"
    return s


def vehicle_until(
    vehicle: MavlinkVehicle, predicate: Callable[[VehicleSnapshot], bool], timeout: float
) -> None:
    assert vehicle.wait_until(predicate, timeout), f"vehicle never matched; last {vehicle.snapshot()}"


def fly(ap: MavlinkAdapter, vehicle: MavlinkVehicle, alt: float = 2.0) -> None:
    assert ap.arm() is True
    ap.takeoff(alt)
    state_until(ap, lambda s: s.alt >= alt - 0.15 and s.in_air, timeout=alt / 2 + 3)
    vehicle_until(vehicle, lambda s: s.guided_submode == "hover", timeout=2)


# -- parameters and registry ------------------------------------------------------------------------


def test_registered_and_parameters_are_validated() -> None:
    assert load_adapter("mavlink") is MavlinkAdapter
    assert MavlinkAdapter.name == "mavlink" and MavlinkAdapter.blocking
    assert MavlinkAdapter.params_model is Params
    assert isinstance(MavlinkAdapter.validate_params({"cells": 4}), Params)  # what the config loader calls
    with pytest.raises(ValueError, match="parameter 'conection': Extra inputs are not permitted"):
        MavlinkAdapter({"conection": "tcp:127.0.0.1:5760"})
    with pytest.raises(ValueError, match="parameter 'velocity_hold': Extra"):  # renamed: setpoint_timeout
        MavlinkAdapter({"velocity_hold": 3.0})
    for bad in (
        {"source_system": 0},
        {"source_system": 256},
        {"target_component": -1},
        {"baud": "fast"},
        {"ack_timeout": 0},
        {"stream_rate_hz": math.nan},
        {"velocity_resend_hz": -1},
        {"connection": ""},
        {"heartbeat_hz": True},
        {"setpoint_timeout": 0},
        {"setpoint_timeout": 11.0},
        {"cells": -1},
        {"configure_vehicle": "yes"},
        {"link_stale_after": math.inf},
        {"signing_key": 7},
    ):
        with pytest.raises(ValueError, match=rf"parameter '{next(iter(bad))}': "):
            MavlinkAdapter(bad)
    with pytest.raises(
        ValueError, match=r"parameters: .*link_stale_after 1 s is shorter than two telemetry periods"
    ):
        MavlinkAdapter({"stream_rate_hz": 1})  # a healthy link would look stale between two messages
    ap = MavlinkAdapter(
        {"velocity_resend_hz": 0, "connect_timeout": 10}
    )  # 0 = never resend; an int is a float
    assert ap.source_system == DEFAULTS["source_system"] == 245
    # the constructor does no I/O; before connect() nothing is known
    assert ap.state() == VehicleState(connected=False, link_age=math.inf)
    with pytest.raises(AutopilotError, match="not connected"):
        ap.arm()
    ap.close()  # idempotent, even unconnected
    # velocity + yaw rate, nothing else (ArduPilot's "use velocity" mask with the yaw-rate bit cleared)
    assert VELOCITY_TYPE_MASK == 0b0000_0101_1100_0111


# -- connecting --------------------------------------------------------------------------------------


def test_connect_over_udp_reads_telemetry(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    assert ap.target == (1, 1)
    s = state_until(ap, lambda s: not math.isnan(s.lat), timeout=3)
    assert s.connected and s.link_age < 1.0
    assert s.lat == pytest.approx(-35.363262, abs=1e-6) and s.lon == pytest.approx(149.165237, abs=1e-6)
    assert s.alt == 0.0 and not s.armed and not s.in_air and s.battery == 100.0
    assert s.mode == "STABILIZE" and not s.autonomous and s.flight_mode is FlightMode.MANUAL
    assert wait_for(lambda: ap.home is not None, 3)
    # our GCS heartbeat goes out as system 245, and telemetry was asked for
    hb = vehicle.received_of("HEARTBEAT")
    assert hb and hb[0].fields["type"] == mav2.MAV_TYPE_GCS
    intervals = [
        r.fields
        for r in vehicle.received_of("COMMAND_LONG")
        if r.fields["command"] == mav2.MAV_CMD_SET_MESSAGE_INTERVAL
    ]
    asked = {int(f["param1"]) for f in intervals}
    assert {
        mav2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
        mav2.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
        mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    } <= asked
    assert (mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAV_RESULT_ACCEPTED) in vehicle.acks
    ap.connect()  # a second connect() is a no-op


def test_connect_over_tcp_and_udpin(vehicle: MavlinkVehicle) -> None:
    tcp = make_ap(vehicle.tcp_url)
    try:
        tcp.connect()
        assert state_until(tcp, lambda s: s.battery == 100.0, 2).connected
    finally:
        tcp.close()
    # SITL's "--out udp:HOST:PORT" style: the vehicle pushes to us, we listen (udpin)
    port = free_udp_port()
    with MavlinkVehicle("127.0.0.1", 0, udp_target=("127.0.0.1", port), **FAST):
        ap = make_ap(f"udpin:127.0.0.1:{port}")
        try:
            ap.connect()
            assert ap.target == (1, 1)
            assert state_until(ap, lambda s: s.link_age < 1.0, 2).connected
        finally:
            ap.close()


def test_connect_fails_clearly_without_a_heartbeat() -> None:
    port = free_udp_port()  # nobody there
    ap = make_ap(f"udpout:127.0.0.1:{port}", connect_timeout=0.5)
    start = time.monotonic()
    with pytest.raises(
        AutopilotError, match=rf"no HEARTBEAT from udpout:127.0.0.1:{port} within 0.5 s.*SITL"
    ):
        ap.connect()
    assert time.monotonic() - start < 2.0
    assert not ap.state().connected
    # TCP: nothing listening is retried until the timeout, then reported with the same hint
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        dead = s.getsockname()[1]
    tcp = make_ap(f"tcp:127.0.0.1:{dead}", connect_timeout=0.6)
    with pytest.raises(AutopilotError, match="cannot open .*refused.*SITL"):
        tcp.connect()
    with pytest.raises(AutopilotError, match="cannot open"):
        make_ap("tcp:nohostport", connect_timeout=5).connect()  # malformed: no retrying


def test_tcp_link_is_reopened_after_the_autopilot_restarts() -> None:
    with MavlinkVehicle("127.0.0.1", None, 0, **FAST) as first:
        port = first.tcp_port
        ap = make_ap(first.tcp_url)
        ap.connect()
    try:
        state_until(ap, lambda s: s.link_age > 0.6, 3)  # silence after the "reboot"
        with MavlinkVehicle("127.0.0.1", None, port, **FAST) as second:
            state_until(ap, lambda s: s.link_age < 0.5, 5)
            # a rebooted autopilot starts with its default rates: telemetry is asked for again
            assert wait_for(lambda: second.received_of("COMMAND_LONG"), 2)
            assert (mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAV_RESULT_ACCEPTED) in second.acks
    finally:
        ap.close()


# -- arming ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("vehicle", [{"boot_delay": 0.6, "gps_delay": 0.9, "ekf_delay": 1.3}], indirect=True)
def test_arm_waits_for_boot_ekf_and_gps(vehicle: MavlinkVehicle) -> None:
    ap = make_ap(vehicle.udp_url)
    try:
        ap.connect()  # during boot
        assert any("booting" in r for r in ap.ready_reasons())
        start = time.monotonic()
        assert ap.arm() is True
        assert time.monotonic() - start > 0.3  # it waited
        assert ap.ready_reasons() == []
        # the vehicle was never asked to arm or change mode before it could: no refusal, one mode change,
        # and the mode did not revert at the end of boot
        assert (mav2.MAV_CMD_COMPONENT_ARM_DISARM, mav2.MAV_RESULT_FAILED) not in vehicle.acks
        assert [a for a in vehicle.acks if a[0] == mav2.MAV_CMD_DO_SET_MODE] == [
            (mav2.MAV_CMD_DO_SET_MODE, mav2.MAV_RESULT_ACCEPTED)
        ]
        snap = vehicle.snapshot()
        assert snap.armed and snap.mode == "GUIDED" and snap.ekf_position_ok and snap.gps_fix_type == 3
        s = state_until(ap, lambda s: s.armed, 1)
        assert s.mode == "GUIDED" and s.autonomous and s.flight_mode is FlightMode.GUIDED and not s.in_air
        assert ap.arm() is True  # already armed in GUIDED: nothing to do
    finally:
        ap.close()


@pytest.mark.parametrize("vehicle", [{"gps_delay": 60.0}], indirect=True)
@pytest.mark.parametrize("ap", [{"ready_timeout": 0.8}], indirect=True)
def test_arm_gives_up_when_never_ready(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    with pytest.raises(AutopilotError, match="not ready to arm after 0.8 s.*GPS fix_type 0"):
        ap.arm()
    assert not vehicle.snapshot().armed and vehicle.snapshot().mode == "STABILIZE"


def test_arm_refused_returns_false_with_the_reason(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    vehicle.refuse_arm = True
    assert ap.arm() is False
    assert "refuse_arm" in ap.last_refusal
    assert not ap.state().armed
    vehicle.refuse_arm = False
    assert ap.arm() is True


# -- flying ------------------------------------------------------------------------------------------


def test_takeoff_climbs_in_guided_and_is_refused_otherwise(
    vehicle: MavlinkVehicle, ap: MavlinkAdapter
) -> None:
    with pytest.raises(AutopilotError, match=r"takeoff to 2 m refused \(FAILED; mode STABILIZE, disarmed\)"):
        ap.takeoff(2.0)
    with pytest.raises(AutopilotError, match="must be > 0"):
        ap.takeoff(math.nan)
    assert ap.arm() is True
    ap.takeoff(2.5)
    climbing = state_until(ap, lambda s: s.alt > 0.5, 2)
    assert climbing.in_air and climbing.vd < 0 and climbing.flight_mode is FlightMode.GUIDED
    # "hover" while the takeoff still runs is not sent: the climb reaches its target
    ap.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.BODY)
    top = state_until(ap, lambda s: s.alt >= 2.4, 3)
    assert top.in_air and top.armed
    vehicle_until(
        vehicle, lambda s: s.guided_submode == "hover" and s.landed_state == mav2.MAV_LANDED_STATE_IN_AIR, 2
    )


def test_velocity_in_ned_and_body_frames(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    fly(ap, vehicle)
    ap.set_velocity(0.0, 3.0, 0.0, 0.0, Frame.NED)  # east
    vehicle_until(vehicle, lambda s: s.east > 1.0, 2)
    snap = vehicle.snapshot()
    assert abs(snap.north) < 0.1 and snap.ve > 2.0
    s = ap.state()
    assert s.ve > 2.0 and 90 - 5 < math.degrees(math.atan2(s.ve, s.vn)) < 90 + 5
    # yaw rate in deg/s, clockwise: turn to face east
    ap.set_velocity(0.0, 0.0, 0.0, 90.0, Frame.BODY)
    vehicle_until(vehicle, lambda s: s.yaw >= 85.0, 2)
    ap.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.BODY)
    heading = vehicle.snapshot().yaw
    assert 85.0 <= heading < 110.0
    assert state_until(ap, lambda s: abs(s.heading - vehicle.snapshot().yaw) < 3.0, 2)
    # forward in the body frame is now east; down is down
    east0 = vehicle.snapshot().east
    ap.set_velocity(2.0, 0.0, 0.5, 0.0, Frame.BODY)
    vehicle_until(vehicle, lambda s: s.east > east0 + 1.0, 2)
    snap = vehicle.snapshot()
    assert snap.vd > 0.3 and abs(snap.vn) < 0.5
    # deg/s in the API, rad/s on the wire only
    rates = {round(r.fields["yaw_rate"], 6) for r in vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED")}
    assert round(math.radians(90.0), 6) in rates and max(rates) <= math.radians(90.0) + 1e-6
    frames = {r.fields["coordinate_frame"] for r in vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED")}
    assert frames == {mav2.MAV_FRAME_LOCAL_NED, mav2.MAV_FRAME_BODY_OFFSET_NED}
    with pytest.raises(AutopilotError, match="non-finite"):
        ap.set_velocity(math.inf, 0.0, 0.0, 0.0, Frame.NED)


@pytest.mark.parametrize("vehicle", [{"guided_timeout": 0.4}], indirect=True)
@pytest.mark.parametrize("ap", [{"setpoint_timeout": 0.8}], indirect=True)
def test_no_setpoint_older_than_the_setpoint_timeout_is_sent(
    vehicle: MavlinkVehicle, ap: MavlinkAdapter
) -> None:
    fly(ap, vehicle, alt=1.5)
    ap.set_velocity(1.0, 0.0, 0.0, 0.0, Frame.NED)  # once
    time.sleep(0.7)
    assert vehicle.snapshot().guided_submode == "velocity"  # kept alive past the 0.4 s GUID_TIMEOUT
    assert wait_for(lambda: not ap.resending, 1.0)
    vehicle_until(vehicle, lambda s: s.guided_submode == "hover" and abs(s.vn) < 0.1, 2)
    sent = [r.t for r in vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED") if r.fields["vx"] == 1.0]
    assert 3 <= len(sent) <= 5, sent  # the call plus resends at 4 Hz for 0.8 s
    assert sent[-1] - sent[0] < 0.8  # the vehicle clock sees the age the adapter's clock allowed
    count = len(vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED"))
    time.sleep(0.5)
    assert len(vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED")) == count


@pytest.mark.parametrize("ap", [{"setpoint_timeout": 5.0}], indirect=True)
def test_hover_is_resent_for_a_second_then_let_go(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    fly(ap, vehicle, alt=1.5)
    ap.set_velocity(1.0, 0.0, 0.0, 0.0, Frame.NED)
    time.sleep(1.2)
    assert ap.resending and vehicle.snapshot().vn > 0.9
    ap.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.BODY)  # the HLC's hover: sent, kept for a second, then let go
    vehicle_until(vehicle, lambda s: abs(s.vn) < 0.05, 2)
    assert wait_for(lambda: not ap.resending, 2)
    count = len(vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED"))
    time.sleep(0.6)
    assert len(vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED")) == count


def test_land_lands_and_disarms(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    fly(ap, vehicle)
    ap.set_velocity(1.0, 0.0, 0.0, 0.0, Frame.NED)
    ap.land()
    assert not ap.resending
    s = state_until(ap, lambda s: s.mode == "LAND", 1)
    assert s.flight_mode is FlightMode.LANDING and s.autonomous
    assert state_until(ap, lambda s: s.vd > 0.3, 2).in_air  # landing: still in the air
    landed = state_until(ap, lambda s: s.landed, 5)
    assert landed.alt == 0.0 and landed.mode == "LAND"
    snap = vehicle.snapshot()
    assert not snap.armed and snap.alt == 0.0


def test_rtl_returns_home_and_lands(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    fly(ap, vehicle)
    home = ap.state()
    ap.set_velocity(4.0, 4.0, 0.0, 0.0, Frame.NED)
    vehicle_until(vehicle, lambda s: math.hypot(s.north, s.east) > 4.0, 3)
    ap.rtl()
    s = state_until(ap, lambda s: s.mode == "RTL", 1)
    assert s.flight_mode is FlightMode.RTL and s.autonomous
    landed = state_until(ap, lambda s: s.landed, 8)
    assert landed.lat == pytest.approx(home.lat, abs=5e-6) and landed.lon == pytest.approx(home.lon, abs=5e-6)
    snap = vehicle.snapshot()
    assert math.hypot(snap.north, snap.east) < 0.5 and not snap.armed


def test_disarm(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    assert ap.arm() is True
    ap.disarm()
    assert state_until(ap, lambda s: not s.armed, 1).landed
    fly(ap, vehicle, alt=1.5)
    with pytest.raises(AutopilotError, match="disarm refused.*flying"):
        ap.disarm()


# -- overrides and faults ----------------------------------------------------------------------------


def test_pilot_switching_to_loiter_is_a_manual_override(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    fly(ap, vehicle, alt=1.5)
    ap.set_velocity(1.0, 0.0, 0.0, 0.0, Frame.NED)
    assert vehicle.pilot_switch_mode("LOITER")
    s = state_until(ap, lambda s: s.mode == "LOITER", 1)
    assert not s.autonomous and s.flight_mode is FlightMode.MANUAL and s.armed and s.in_air
    assert s.failsafe == ""  # no failsafe explains it: a pilot
    assert not ap.resending  # a pilot has it: never fight them with an old target
    ap.set_velocity(2.0, 0.0, 0.0, 0.0, Frame.NED)  # ignored outside GUIDED, not kept
    assert not ap.resending
    # the pilot lands
    assert vehicle.pilot_switch_mode("LAND")
    assert state_until(ap, lambda s: s.landed, 5).flight_mode is FlightMode.LANDING


def test_heartbeat_silence_is_link_loss(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    state_until(ap, lambda s: s.link_age < 0.3, 1)
    vehicle.stop_heartbeats()
    s = state_until(ap, lambda s: s.link_age > 1.0, 2)
    assert s.connected  # the link is open; the vehicle is silent
    age = s.link_age
    time.sleep(0.3)
    assert ap.state().link_age > age + 0.2
    start = time.monotonic()
    with pytest.raises(AutopilotError, match="no COMMAND_ACK"):
        ap.land()
    assert time.monotonic() - start < 1.5  # two attempts of ack_timeout 0.5 s
    state_until(ap, lambda s: s.link_age > 2.1, 2)
    requests = len(vehicle.received_of("COMMAND_LONG"))
    vehicle.resume_heartbeats()
    state_until(ap, lambda s: s.link_age < 0.5, 2)
    # after more than 2 s of silence the autopilot may have rebooted: telemetry is asked for again
    assert wait_for(lambda: len(vehicle.received_of("COMMAND_LONG")) > requests, 2)


def test_battery(vehicle: MavlinkVehicle, ap: MavlinkAdapter) -> None:
    assert state_until(ap, lambda s: s.battery_known, 2).battery == 100.0
    vehicle.set_battery(17)
    assert state_until(ap, lambda s: s.battery == 17.0, 2).battery_known


def test_close_is_idempotent_and_final(vehicle: MavlinkVehicle) -> None:
    ap = make_ap(vehicle.udp_url)
    ap.connect()
    ap.close()
    ap.close()
    assert ap.state() == VehicleState(connected=False, link_age=math.inf)
    with pytest.raises(AutopilotError, match="not connected"):
        ap.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.NED)
    with pytest.raises(AutopilotError, match="not connected"):
        ap.land()
