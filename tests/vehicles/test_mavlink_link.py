"""`mavlink.link`: `MemoryLink` carries real MAVLink 2 frames, signed or not, with no socket."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import pytest
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.mavlink import dialect
from antalate_lcm.vehicles.mavlink.link import LinkClosed, MemoryLink, _convert

KEY = bytes(range(32))


def received(link: MemoryLink) -> Any:
    """The next message off ``link``; a second without one fails the test."""
    msg = link.recv(1.0)
    assert msg is not None, "nothing received within 1 s"
    return msg


def echo_ack(msg: Any) -> Iterable[Any]:
    if msg.get_type() == "COMMAND_LONG":
        yield mav.MAVLink_command_ack_message(msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0, 245, 191)


def test_frames_are_real_bytes_both_ways() -> None:
    wire: list[bytes] = []
    link = MemoryLink(wire.append, source_system=7, source_component=9)
    link.send(dialect.gcs_heartbeat())
    link.send(dialect.command_long((1, 1), mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 3.0))
    assert [frame[0] for frame in wire] == [mav.PROTOCOL_MARKER_V2] * 2
    parser = mav.MAVLink(None)
    first, second = (parser.parse_buffer(frame)[0] for frame in wire)
    assert first.get_type() == "HEARTBEAT" and (first.get_srcSystem(), first.get_srcComponent()) == (7, 9)
    assert second.get_seq() == 1 and second.param7 == 3.0
    vehicle = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = mav.MAVLink_heartbeat_message(2, 3, 0, 4, 3, 3).pack(vehicle)
    link.feed(hb[:5])  # half a frame so far: a stream link delivers bytes, not messages
    assert link.recv(0.01) is None
    link.feed(hb[5:])
    got = link.recv(1.0)
    assert got is not None and got.get_type() == "HEARTBEAT" and got.custom_mode == 4


def test_answering_link_replies_through_the_codec() -> None:
    link = MemoryLink.answering(echo_ack)
    link.send(dialect.command_long((1, 1), mav.MAV_CMD_DO_SET_MODE, 0, 1, 4))
    reply = received(link)
    assert reply.get_type() == "COMMAND_ACK" and reply.command == mav.MAV_CMD_DO_SET_MODE
    assert (reply.get_srcSystem(), reply.get_srcComponent()) == (1, 1)
    link.push(mav.MAVLink_extended_sys_state_message(0, mav.MAV_LANDED_STATE_IN_AIR))
    assert received(link).landed_state == mav.MAV_LANDED_STATE_IN_AIR
    with pytest.raises(TypeError):
        MemoryLink(lambda _data: None).push(dialect.gcs_heartbeat())


def test_a_failing_handler_is_logged_and_the_link_goes_on(caplog: pytest.LogCaptureFixture) -> None:
    def broken(msg: Any) -> Iterable[Any]:
        if msg.get_type() == "HEARTBEAT":
            raise RuntimeError("vehicle bug")
        yield from echo_ack(msg)

    link = MemoryLink.answering(broken)
    link.send(dialect.gcs_heartbeat())  # the sender (the adapter's transmit thread) is not hit
    link.send(dialect.command_long((1, 1), mav.MAV_CMD_NAV_TAKEOFF, 0))
    assert received(link).get_type() == "COMMAND_ACK"
    assert "MemoryLink handler failed on HEARTBEAT" in caplog.text


def test_signed_link_drops_what_the_vehicle_sends_without_the_key() -> None:
    signed = MemoryLink.answering(echo_ack, signing_key=KEY)
    signed.send(dialect.command_long((1, 1), mav.MAV_CMD_NAV_TAKEOFF, 0))
    assert received(signed).get_type() == "COMMAND_ACK"  # both ends share the key
    forged = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    signed.feed(mav.MAVLink_heartbeat_message(2, 3, 0, 4, 3, 3).pack(forged))  # unsigned
    bad = received(signed)
    assert bad.get_type() == "BAD_DATA" and "signature" in str(bad.reason)
    mismatched = MemoryLink.answering(echo_ack, signing_key=bytes(32))
    wire: list[bytes] = []
    ours = MemoryLink(wire.append, signing_key=KEY)
    ours.send(dialect.command_long((1, 1), mav.MAV_CMD_NAV_TAKEOFF, 0))
    mismatched.feed(wire[0])  # our signed frame, parsed by a link with another key
    assert received(mismatched).get_type() == "BAD_DATA"


def test_closed_link_refuses_to_send_and_receive() -> None:
    link = MemoryLink(lambda _data: None)
    link.close()
    assert link.closed
    with pytest.raises(LinkClosed):
        link.send(dialect.gcs_heartbeat())
    with pytest.raises(OSError):
        link.recv(0.01)


def test_a_message_converts_to_mavlink_1_for_a_codec_that_has_not_heard_mavlink_2() -> None:
    msg = _convert(dialect.param_set((1, 1), "FS_GCS_ENABLE", 1.0, mav.MAV_PARAM_TYPE_INT8), mav1)
    assert isinstance(msg, mav1.MAVLink_param_set_message) and msg.param_id == "FS_GCS_ENABLE"
    frame = msg.pack(mav1.MAVLink(None, srcSystem=245, srcComponent=191))
    assert frame[0] == mav1.PROTOCOL_MARKER_V1
    back = mav.MAVLink(None).parse_buffer(frame)[0]
    assert back.param_id == "FS_GCS_ENABLE" and back.param_value == 1.0
