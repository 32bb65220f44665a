"""A whole mission through `MavlinkAutopilot` over a `MemoryLink`: no socket anywhere (issue #14).

MC + HLC(``mavlink``) + a BMA running ``auto_operator`` (the operator: TAKEOFF, then RTL after a
second of MISSION) on one ``memq://`` bus in this process; the adapter's link is a `MemoryLink` to the
ArduCopter emulator (`MavlinkVehicle.memory_link`), which binds no socket either. Every frame is
still made and parsed by pymavlink, so this is the adapter exactly as over TCP, only in memory.

Also the scripted form users get for their own tests: `MemoryLink.answering` with a few lines of
vehicle, connected to by the adapter.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.autopilot.mavlink import MavlinkAutopilot, MemoryLink, Params
from antalate_lcm.bma.node import BmaNode
from antalate_lcm.bus import Bus
from antalate_lcm.config import parse_config
from antalate_lcm.executor import Executor
from antalate_lcm.hlc.node import HlcNode
from antalate_lcm.mc.node import McNode
from antalate_lcm.msgs import hlc_state_t, mc_state_t
from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.node import Context, Node
from tests.emulators.mavlink_vehicle import MavlinkVehicle
from tests.test_mavlink_e2e import AP, FAST


@dataclass
class Seen:
    t: float
    state: int


class MemoryAgent:
    """The agent's nodes with the adapter on a `MemoryLink` to `vehicle`; records MC and HLC states."""

    def __init__(self, vehicle: MavlinkVehicle) -> None:
        doc = {
            "agent": {"name": "copter"},
            "buses": {"lan": "memq://"},
            "hlc": {
                "autopilot": "mavlink",
                "default_takeoff_altitude": 3.0,
                "link_timeout": 1.5,
                "autopilot_params": {"connection": "memory:emulator", **AP},
            },
            "bma": [
                {
                    "name": "operator",
                    "behaviors": [
                        {
                            "plugin": "auto_operator",
                            "activate_on": ["STANDBY", "MISSION"],
                            "params": {"altitude": 3.0, "max_flights": 1, "retry": 0.5, "rtl_after": 1.0},
                        }
                    ],
                }
            ],
        }
        config = parse_config(doc, "mavlink-memory.toml")
        self.vehicle = vehicle
        self.links: list[MemoryLink] = []
        self.context = Context(Bus(config.buses), Executor())
        self.autopilot = MavlinkAutopilot(
            config.hlc.autopilot_params, clock=self.context.executor.clock, link=self._open
        )
        self.mc: list[Seen] = []
        self.hlc: list[Seen] = []
        self.probe = Node(config, self.context, name="probe")
        self.nodes: list[Node] = [
            HlcNode(config, self.context, self.autopilot),
            McNode(config, self.context),
            *(BmaNode(config, self.context, bma) for bma in config.bma),
        ]

    def _open(self, params: Params) -> MemoryLink:
        link = self.vehicle.memory_link(
            source_system=params.source_system, source_component=params.source_component
        )
        self.links.append(link)
        return link

    def start(self) -> MemoryAgent:
        self.context.executor.start()
        self.probe.start()
        self.probe.subscribe("MC_STATE", lambda m: self._seen(self.mc, m))
        self.probe.subscribe("HLC_STATE", lambda m: self._seen(self.hlc, m))
        for node in self.nodes:
            node.start()
        return self

    def stop(self) -> None:
        for node in reversed([self.probe, *self.nodes]):
            node.stop()
        self.context.close()

    @staticmethod
    def _seen(into: list[Seen], msg: mc_state_t | hlc_state_t) -> None:
        if not into or into[-1].state != msg.state:
            into.append(Seen(time.monotonic(), msg.state))

    def wait(self, which: str, state: int, timeout: float = 10.0, since: float = 0.0) -> Seen:
        seen = self.mc if which == "mc" else self.hlc
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hit = next((s for s in list(seen) if s.state == state and s.t >= since), None)
            if hit is not None:
                return hit
            time.sleep(0.02)
        raise AssertionError(f"{which} never reached state {state} (seen {[s.state for s in seen]})")


@pytest.fixture
def agent() -> Iterator[MemoryAgent]:
    vehicle = MavlinkVehicle(udp_port=None, tcp_port=None, **FAST).start()
    made = MemoryAgent(vehicle).start()
    yield made
    made.stop()
    vehicle.stop()


def test_mission_over_a_memory_link(agent: MemoryAgent) -> None:
    """Operator TAKEOFF -> AIRBORNE/MISSION -> RTL -> landed at home and disarmed, READY/STANDBY again."""
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
    # the adapter spoke over the memory link only, and the vehicle bound nothing
    assert len(agent.links) == 1 and agent.vehicle.udp_port is None and agent.vehicle.tcp_port is None
    assert agent.vehicle.received_of("COMMAND_LONG") and agent.vehicle.received_of("HEARTBEAT")


def _scripted_copter(heard: list[str]) -> Any:
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
    ap = MavlinkAutopilot(
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
