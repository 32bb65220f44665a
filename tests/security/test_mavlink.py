"""MAVLink: the link between the HLC and the flight controller, on a network an attacker shares
(a UDP telemetry link, a radio). The agent ``foxtrot`` (``antalate agent``) flies the emulated
ArduCopter (tests/emulators/mavlink_vehicle.py, its own process) through the ``mavlink`` adapter
with MAVLink 2 signing on both sides (``signing_key``). The adapter listens like a ground station
(``udpin``), the vehicle pushes to it and takes commands on its own UDP port, as SITL does.

The attacker speaks raw MAVLink 2 from its own UDP socket: commands to the vehicle posing as the
ground station, forged vehicle messages to the adapter, and signed frames it recorded, replayed.
What "nothing moved" means comes from the emulator's own state, not from the link.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.emulators.mavlink_vehicle import COPTER_MODES
from tests.harness.jsonl import JsonLinesProcess
from tests.harness.polling import wait_for
from tests.harness.process import stop_process
from tests.security.harness import (
    DISARMED,
    HOME,
    AgentRun,
    PeerClient,
    Swarm,
    agent_doc,
    command,
)

pytestmark = pytest.mark.netns

VEHICLE_PORT = 14560  # the vehicle's own UDP port (it answers whoever sends to it)
ADAPTER_PORT = 14551  # where the adapter listens (udpin) and the vehicle pushes
MAV_KEY = hashlib.sha256(b"security suite mavlink passphrase").digest()
GCS = (245, 191)  # the adapter's system/component ids (its defaults)
COPTER = (1, 1)


class Copter(JsonLinesProcess):
    def snap(self) -> dict[str, Any]:
        reply = self.call(op="snapshot")
        assert reply["ok"], reply
        return reply


@pytest.fixture(scope="module")
def copter(swarm: Swarm) -> Iterator[tuple[Copter, AgentRun]]:
    args = [
        "tests.security.mav_vehicle",
        "--udp-port",
        str(VEHICLE_PORT),
        "--udp-target",
        f"127.0.0.1:{ADAPTER_PORT}",
        "--home",
        f"{HOME[0]},{HOME[1]}",
    ]
    if not DISARMED:
        args += ["--signing-key", MAV_KEY.hex()]
    proc = swarm.netns.peer(*args)
    vehicle = Copter(proc, "the MAVLink vehicle")
    doc = agent_doc(
        "foxtrot",
        swarm.tmp / "state",
        hlc={
            "autopilot": "mavlink",
            "link_timeout": 2.0,
        },
    )
    doc["hlc"]["autopilot_params"] = {
        "connection": f"udpin:127.0.0.1:{ADAPTER_PORT}",
        "stream_rate_hz": 20.0,
        "connect_timeout": 5.0,
        "ready_timeout": 5.0,
        "ack_timeout": 0.5,
        **({} if DISARMED else {"signing_key": MAV_KEY.hex()}),
    }
    run = swarm.agent("foxtrot", doc)
    agent = swarm.start_agents_process("foxtrot", ["foxtrot"])
    try:
        run.wait_mc("STANDBY", timeout=60)
        yield vehicle, run
    finally:
        stop_process(agent)
        stop_process(proc)


def encoder(src: tuple[int, int], key: bytes | None) -> mav2.MAVLink:
    enc = mav2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    if key is not None:
        enc.signing.secret_key = key
        enc.signing.sign_outgoing = True
        enc.signing.link_id = 0
        enc.signing.timestamp = int((time.time() - 1420070400) * 1e5)
    return enc


def launch_commands(enc: mav2.MAVLink) -> list[bytes]:
    """What flies a copter away: GUIDED, arm (forced), take off, fly north at 3 m/s."""
    guided = COPTER_MODES["GUIDED"]
    msgs = [
        enc.set_mode_encode(1, mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, guided),
        enc.command_long_encode(
            1, 1, mav2.MAV_CMD_DO_SET_MODE, 0, mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, guided, 0, 0, 0, 0, 0
        ),
        enc.command_long_encode(1, 1, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 21196, 0, 0, 0, 0, 0),
        enc.command_long_encode(1, 1, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 10.0),
        enc.set_position_target_local_ned_encode(
            0, 1, 1, mav2.MAV_FRAME_LOCAL_NED, 0b0000111111000111, 0, 0, 0, 3.0, 0, 0, 0, 0, 0, 0, 0
        ),
    ]
    return [m.pack(enc) for m in msgs]


def unchanged(
    vehicle: Copter, run: AgentRun, before: dict[str, Any], n_mc: int, n_hlc: int
) -> dict[str, Any]:
    time.sleep(1.0)
    after = vehicle.snap()
    s0, s1 = before["snapshot"], after["snapshot"]
    assert not s1["armed"] and s1["alt"] < 0.2, f"the vehicle was armed or took off: {s1}"
    assert s1["mode"] == s0["mode"], f"the vehicle's mode changed {s0['mode']} -> {s1['mode']}"
    assert abs(s1["north"] - s0["north"]) + abs(s1["east"] - s0["east"]) < 0.3, s1
    assert run.transitions("mc")[n_mc:] == [], run.transitions("mc")[n_mc:]
    assert run.transitions("hlc")[n_hlc:] == [], run.transitions("hlc")[n_hlc:]
    return after


def marks(vehicle: Copter, run: AgentRun) -> tuple[dict[str, Any], int, int]:
    assert run.mc_state() == "STANDBY"
    return vehicle.snap(), len(run.transitions("mc")), len(run.transitions("hlc"))


@pytest.mark.attack("unsigned MAVLink commands to the vehicle, posing as the ground station")
def test_unsigned_mavlink_commands(copter: tuple[Copter, AgentRun], attacker: PeerClient) -> None:
    vehicle, run = copter
    before, n_mc, n_hlc = marks(vehicle, run)
    attacker.udp_open()
    frames = launch_commands(encoder(GCS, None)) + launch_commands(encoder((255, 190), None))
    attacker.udp_send(VEHICLE_PORT, frames * 5, gap=0.01)
    after = unchanged(vehicle, run, before, n_mc, n_hlc)
    assert after["signing_rejected"] > before["signing_rejected"], "the vehicle did not even see the attack"


@pytest.mark.attack("MAVLink commands to the vehicle signed with another key")
def test_wrongly_signed_mavlink_commands(copter: tuple[Copter, AgentRun], attacker: PeerClient) -> None:
    vehicle, run = copter
    before, n_mc, n_hlc = marks(vehicle, run)
    attacker.udp_open()
    frames = launch_commands(encoder(GCS, os.urandom(32))) + launch_commands(encoder(GCS, b"\x00" * 32))
    attacker.udp_send(VEHICLE_PORT, frames * 5, gap=0.01)
    after = unchanged(vehicle, run, before, n_mc, n_hlc)
    assert after["signing_rejected"] > before["signing_rejected"], "the vehicle did not even see the attack"


@pytest.mark.attack("signed MAVLink frames recorded off the link, replayed to the vehicle after landing")
def test_replayed_signed_mavlink_frames(
    swarm: Swarm, copter: tuple[Copter, AgentRun], attacker: PeerClient, operator: PeerClient
) -> None:
    vehicle, run = copter
    assert run.mc_state() == "STANDBY"
    # The attacker joins the adapter's listeners (udpin answers whoever sends): it now receives every
    # signed frame the adapter sends the vehicle.
    attacker.udp_open()
    attacker.udp_send(ADAPTER_PORT, [b"\xfd"])
    _, start = attacker.udp_recv()
    n = len(run.transitions("mc"))
    command(operator, swarm, "foxtrot", "TAKEOFF")
    run.wait_mc("MISSION", timeout=30, after=n)
    n = len(run.transitions("mc"))
    command(operator, swarm, "foxtrot", "LAND")
    run.wait_mc("STANDBY", timeout=30, after=n)
    assert wait_for(lambda: not vehicle.snap()["snapshot"]["armed"], 15.0, 0.2), "the vehicle did not disarm"
    recorded, _ = attacker.udp_recv(start)
    assert len(recorded) > 20, f"the attacker recorded only {len(recorded)} datagrams"
    before, n_mc, n_hlc = marks(vehicle, run)
    attacker.udp_send(VEHICLE_PORT, recorded, gap=0.002)
    after = unchanged(vehicle, run, before, n_mc, n_hlc)
    assert after["signing_rejected"] > before["signing_rejected"]


def forged_vehicle(enc: mav2.MAVLink) -> list[bytes]:
    """A vehicle that says: a pilot switched to LOITER, it is armed and in the air, 3 % battery, far away."""
    armed = mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav2.MAV_MODE_FLAG_SAFETY_ARMED
    msgs = [
        enc.heartbeat_encode(
            mav2.MAV_TYPE_QUADROTOR,
            mav2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            armed,
            COPTER_MODES["LOITER"],
            mav2.MAV_STATE_ACTIVE,
            3,
        ),
        enc.sys_status_encode(0, 0, 0, 0, 9000, 0, 3, 0, 0, 0, 0, 0, 0),
        enc.extended_sys_state_encode(0, mav2.MAV_LANDED_STATE_IN_AIR),
        enc.global_position_int_encode(
            0, int((HOME[0] + 0.05) * 1e7), int((HOME[1] + 0.05) * 1e7), 50_000, 40_000, 0, 0, 0, 9000
        ),
    ]
    return [m.pack(enc) for m in msgs]


@pytest.mark.parametrize("signed", ["unsigned", "one-frame-signed-with-another-key"])
@pytest.mark.attack("forged vehicle messages to the adapter (pilot took over, armed, 3 % battery, far away)")
def test_forged_vehicle_messages_to_the_adapter(
    copter: tuple[Copter, AgentRun], attacker: PeerClient, operator: PeerClient, signed: str
) -> None:
    """Last in this module: if a forged frame breaks the link, the agent stays down.

    The signed variant is one datagram: a HEARTBEAT ("LOITER, armed") in the vehicle's own stream
    (link 0, system 1, component 1), signed with a key of the attacker's and stamped an hour ahead.
    Its signature is wrong, so it must change nothing, not even the stream's replay timestamp.
    """
    vehicle, run = copter
    before, n_mc, n_hlc = marks(vehicle, run)
    attacker.udp_open()
    mark = operator.mark()
    if signed == "unsigned":
        frames = forged_vehicle(encoder(COPTER, None)) * 10
    else:
        enc = encoder(COPTER, os.urandom(32))
        enc.signing.timestamp += 3600 * 100_000  # units of 10 us
        frames = forged_vehicle(enc)[:1]
    attacker.udp_send(ADAPTER_PORT, frames, gap=0.02)
    # Longer than the HLC's link_timeout (2 s): a link the forgery broke is declared lost by then.
    time.sleep(2.0)
    unchanged(vehicle, run, before, n_mc, n_hlc)
    # What the agent tells the operator (its genuine telemetry) never carried the forgery.
    seen = operator.history("foxtrot/TELEMETRY", "telemetry_t", since=mark, genuine=True)
    assert seen, "foxtrot published no signed telemetry during the attack"
    for t in seen:
        assert not t["armed"] and not t["in_air"] and t["battery"] > 50.0 and t["mode"] != "LOITER", t
        assert abs(t["lat"] - HOME[0]) < 1e-4 and abs(t["lon"] - HOME[1]) < 1e-4, t
