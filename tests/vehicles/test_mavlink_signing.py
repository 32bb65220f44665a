"""MAVLink 2 signing between `MavlinkAdapter` and the emulated ArduCopter (pymavlink's signing, 127.0.0.1).

A signed link flies; a wrong key or an unsigned peer is refused with a clear message, and every
message dropped for its signature is counted on both sides; a forged unsigned message injected into a
signed link changes nothing.
"""

from __future__ import annotations

import hashlib
import socket
import time
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from antalate_lcm.vehicles import AutopilotError, Frame
from antalate_lcm.vehicles.mavlink.link import PymavlinkLink
from antalate_lcm.vehicles.mavlink.signing import signing_key
from tests.emulators.mavlink_vehicle import COPTER_MODES, MavlinkVehicle
from tests.harness.polling import wait_for
from tests.vehicles.test_mavlink_adapter import FAST, fly, make_ap, state_until, vehicle_until

PASSPHRASE = "correct horse battery staple"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()  # MAVProxy's `signing setup PASSPHRASE`


def vehicle(made: list[Any], key: bytes | None) -> MavlinkVehicle:
    v = MavlinkVehicle("127.0.0.1", 0, 0, **FAST, signing_key=key).start()
    made.append(v)
    return v


def test_key_from_passphrase_or_hex() -> None:
    assert signing_key(PASSPHRASE) == KEY and len(KEY) == 32
    assert signing_key(KEY.hex()) == KEY and signing_key(f"  {KEY.hex().upper()} ") == KEY
    with pytest.raises(ValueError, match="empty"):
        signing_key("  ")


@pytest.mark.parametrize("tcp", [False, True])
def test_signed_link_flies(made: list[Any], tcp: bool) -> None:
    v = vehicle(made, KEY)
    ap = make_ap(v.tcp_url if tcp else v.udp_url, signing_key=PASSPHRASE)
    made.append(ap)
    ap.connect()
    fly(ap, v, alt=1.5)
    ap.set_velocity(1.0, 0.0, 0.0, 0.0, Frame.NED)
    vehicle_until(v, lambda s: s.vn > 0.8, 2)
    ap.land()
    assert state_until(ap, lambda s: s.landed, 5)
    assert ap.signing_rejected == 0 and v.signing_rejected == 0


def test_wrong_key_is_refused_and_counted(made: list[Any]) -> None:
    v = vehicle(made, KEY)
    ap = make_ap(v.udp_url, signing_key="not the key", connect_timeout=1.0)
    with pytest.raises(
        AutopilotError,
        match=r"dropped for a missing or wrong MAVLink 2 signature: does the vehicle "
        r"have the same signing key\?",
    ):
        ap.connect()
    assert ap.signing_rejected > 0
    assert wait_for(lambda: v.signing_rejected > 0, 1)  # the vehicle dropped ours too
    assert not v.received_of("HEARTBEAT") and not v.received_of("COMMAND_LONG")


def test_unsigned_vehicle_is_refused_by_a_signing_adapter(made: list[Any]) -> None:
    v = vehicle(made, None)
    ap = make_ap(v.udp_url, signing_key=PASSPHRASE, connect_timeout=1.0)
    with pytest.raises(AutopilotError, match="signature"):
        ap.connect()
    assert ap.signing_rejected > 0


def test_signing_vehicle_ignores_an_unsigned_adapter(made: list[Any]) -> None:
    v = vehicle(made, KEY)
    ap = make_ap(v.udp_url)  # no key: its HEARTBEAT and commands are dropped by the vehicle
    made.append(ap)
    ap.connect()  # it hears the signed vehicle (pymavlink without a key does not check)...
    with pytest.raises(AutopilotError, match="no COMMAND_ACK"):
        ap.land()  # ...but the vehicle never hears it
    assert v.signing_rejected > 0 and not v.received_of("COMMAND_LONG")


def test_forged_unsigned_messages_on_a_signed_link_change_nothing(made: list[Any]) -> None:
    v = vehicle(made, KEY)
    ap = make_ap(v.udp_url, signing_key=KEY.hex())
    made.append(ap)
    ap.connect()
    fly(ap, v, alt=1.5)
    enc = v.encoder
    forged_mode = enc.heartbeat_encode(
        mav2.MAV_TYPE_QUADROTOR,
        mav2.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav2.MAV_MODE_FLAG_SAFETY_ARMED,
        COPTER_MODES["LOITER"],
        mav2.MAV_STATE_ACTIVE,
        3,
    )
    forged_battery = enc.sys_status_encode(0, 0, 0, 0, 9000, 0, 3, 0, 0, 0, 0, 0, 0)
    v.inject(forged_mode)  # unsigned: "a pilot took over"
    v.inject(forged_battery, key=b"\x01" * 32)  # signed with another key: "3 % left"
    assert wait_for(lambda: ap.signing_rejected >= 2, 2)
    s = ap.state()
    assert s.mode == "GUIDED" and s.battery == 100.0 and s.voltage > 12.0
    # the forgery carried a newer timestamp than the vehicle's: it must not make the vehicle's genuine
    # frames look like replays (pymavlink records the timestamp before it checks the signature)
    time.sleep(1.0)
    assert ap.state().link_age < 0.5 and ap.state().mode == "GUIDED"
    # an attacker's unsigned command to the vehicle (posing as us, system 245) is dropped too
    v_rejected = v.signing_rejected
    attacker = mav2.MAVLink(None, srcSystem=245, srcComponent=191)
    land = attacker.command_long_encode(1, 1, mav2.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
    forger = mav2.MAVLink(None, srcSystem=245, srcComponent=191)  # signed, wrong key, a later timestamp
    forger.signing.secret_key, forger.signing.sign_outgoing = b"\x02" * 32, True
    forger.signing.timestamp = int((time.time() - 1420070400 + 3600) * 1e5)
    ours = ap._link
    assert isinstance(ours, PymavlinkLink)
    forger.signing.link_id = ours.codec.signing.link_id  # our stream: an attacker reads it off any frame
    rtl = forger.command_long_encode(1, 1, mav2.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.sendto(land.pack(attacker), ("127.0.0.1", v.udp_port))
        sock.sendto(rtl.pack(forger), ("127.0.0.1", v.udp_port))
        assert wait_for(lambda: v.signing_rejected >= v_rejected + 2, 2)
    assert v.snapshot().mode == "GUIDED"
    ap.land()  # our genuine, signed commands still count (the forged timestamp was not recorded)
    assert state_until(ap, lambda s: s.mode == "LAND", 2)
