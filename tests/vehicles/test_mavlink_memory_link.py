"""A whole mission through `MavlinkAdapter` over a `MemoryLink`: no socket anywhere (issue #14).

MC + HLC(``mavlink``) + a BMA running ``auto_operator`` (the operator: TAKEOFF, then RTL after a
second of MISSION) on one ``memq://`` bus in this process, assembled as in test_mavlink_e2e.py; the
adapter's link is a `MemoryLink` to the ArduCopter emulator (`MavlinkVehicle.memory_link`), which binds
no socket either. Every frame is still made and parsed by pymavlink: the adapter runs exactly as over
TCP, only in memory.

Also the scripted form users get for their own tests: `MemoryLink.answering` with a few lines of
vehicle, connected to by the adapter.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.vehicles.mavlink import MavlinkAdapter, MemoryLink, Params
from tests.emulators.mavlink_vehicle import BRISK, MavlinkVehicle
from tests.vehicles.test_mavlink_e2e import InProcessAgent


@pytest.fixture
def memory_copter() -> Iterator[tuple[InProcessAgent, list[MemoryLink]]]:
    vehicle = MavlinkVehicle(udp_port=None, tcp_port=None, **BRISK).start()
    links: list[MemoryLink] = []

    def open_link(params: Params) -> MemoryLink:
        links.append(
            vehicle.memory_link(source_system=params.source_system, source_component=params.source_component)
        )
        return links[-1]

    agent = InProcessAgent(vehicle, operator={"rtl_after": 1.0}, link=open_link).start()
    yield agent, links
    agent.stop()
    vehicle.stop()


def test_mission_over_a_memory_link(memory_copter: tuple[InProcessAgent, list[MemoryLink]]) -> None:
    """Operator TAKEOFF -> AIRBORNE/MISSION -> RTL -> landed at home and disarmed, READY/STANDBY again."""
    agent, links = memory_copter
    agent.wait("mc", M.STANDBY)
    takeoff = agent.wait("mc", M.TAKEOFF)
    agent.wait("hlc", H.TAKEOFF, since=takeoff.t)
    airborne = agent.wait("hlc", H.AIRBORNE, since=takeoff.t)
    mission = agent.wait("mc", M.MISSION, since=airborne.t)
    snap = agent.vehicle.snapshot()
    assert snap.armed and snap.mode == "GUIDED" and snap.alt > 2.5
    rtl = agent.wait("mc", M.RTL, since=mission.t)  # the operator's RTL after a second of MISSION
    agent.wait("hlc", H.RTL, timeout=4, since=rtl.t)
    assert agent.vehicle.wait_until(lambda s: s.mode == "RTL", 4)
    agent.wait("hlc", H.READY, timeout=15, since=rtl.t)
    agent.wait("mc", M.STANDBY, timeout=5, since=rtl.t)
    after = agent.vehicle.snapshot()
    assert not after.armed and after.alt < 0.2 and math.hypot(after.north, after.east) < 0.5
    assert not agent.errors  # not a single hlc_error_t on the way
    # the adapter spoke over one memory link only, and the vehicle bound nothing
    assert len(links) == 1 and agent.vehicle.udp_port is None and agent.vehicle.tcp_port is None
    assert agent.vehicle.received_of("COMMAND_LONG") and agent.vehicle.received_of("HEARTBEAT")


def _scripted_copter(heard: list[str]) -> Callable[[Any], Iterable[Any]]:
    """A few lines of vehicle: HEARTBEAT with telemetry for every GCS HEARTBEAT, ACCEPTED for any command."""
    mode = {"custom_mode": 0}

    def answer(msg: Any) -> Iterable[Any]:
        heard.append(msg.get_type())
        if msg.get_type() == "HEARTBEAT":
            yield mav.MAVLink_heartbeat_message(
                mav.MAV_TYPE_QUADROTOR,
                mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                mode["custom_mode"],
                mav.MAV_STATE_STANDBY,
                3,
            )
            yield mav.MAVLink_global_position_int_message(0, -353632620, 1491652370, 584000, 0, 0, 0, 0, 9000)
            yield mav.MAVLink_extended_sys_state_message(0, mav.MAV_LANDED_STATE_ON_GROUND)
        elif msg.get_type() == "COMMAND_LONG":
            if msg.command == mav.MAV_CMD_DO_SET_MODE:
                mode["custom_mode"] = int(msg.param2)
            yield mav.MAVLink_command_ack_message(
                msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )

    return answer


def test_answering_link_connects_the_adapter_to_a_scripted_vehicle() -> None:
    """What a user's own test does without SITL: the adapter connects, reads the picture, sets a mode."""
    heard: list[str] = []
    link = MemoryLink.answering(_scripted_copter(heard))
    ap = MavlinkAdapter(
        {"heartbeat_hz": 20.0, "connect_timeout": 5.0, "ack_timeout": 0.5, "check_vehicle": False},
        link=lambda _params: link,
    )
    ap.connect()
    try:
        state = ap.state()
        assert state.connected and state.link_age < 1.0 and not state.armed and not state.in_air
        assert state.lat == pytest.approx(-35.363262) and state.heading == pytest.approx(90.0)
        assert ap.target == (1, 1)
        ap.rtl()  # DO_SET_MODE acknowledged, then a HEARTBEAT shows RTL
        assert ap.state().mode == "RTL"
        assert "COMMAND_LONG" in heard and "HEARTBEAT" in heard
    finally:
        ap.close()
    assert link.closed
