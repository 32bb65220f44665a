"""`mavlink.streams`: telemetry requests one at a time, REQUEST_DATA_STREAM for old firmware (pure, no sockets)."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.mavlink.dialect import DATA_STREAMS, STREAMS
from antalate_lcm.vehicles.mavlink.streams import StreamRequest
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle

TARGET = (1, 1)


def ack(v: Vehicle, result: int) -> None:
    v.update(mav.MAVLink_command_ack_message(mav.MAV_CMD_SET_MESSAGE_INTERVAL, result, 0, 0, 245, 191), 0.0)


def only(msgs: list[Any]) -> Any:
    assert len(msgs) == 1
    return msgs[0]


def test_one_request_at_a_time_each_on_its_answer() -> None:
    v, req = Vehicle(), StreamRequest(rate=10.0, ack_timeout=0.5)
    first = only(req.step(v, TARGET, 0.0))
    assert (
        first.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL
        and first.param1 == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    )
    assert first.param2 == 1e5 and req.deadline == 0.5  # 10 Hz
    assert req.step(v, TARGET, 0.1) == [] and not req.answered(v)  # still waiting
    ack(v, mav.MAV_RESULT_ACCEPTED)
    assert req.answered(v)
    second = only(req.step(v, TARGET, 0.2))
    assert second.param1 == mav.MAVLINK_MSG_ID_ATTITUDE and not req.answered(v)
    sent = 2
    while not req.done:
        ack(v, mav.MAV_RESULT_ACCEPTED)
        sent += len(req.step(v, TARGET, 0.3))
    assert sent == len(STREAMS)


def test_home_position_is_asked_for_slower() -> None:
    v, req = Vehicle(), StreamRequest(rate=10.0, ack_timeout=0.5)
    msgs = []
    while not req.done:
        msgs += req.step(v, TARGET, 0.0)
        ack(v, mav.MAV_RESULT_ACCEPTED)
    home = next(m for m in msgs if m.param1 == mav.MAVLINK_MSG_ID_HOME_POSITION)
    assert home.param2 == 1e6  # 1 Hz: a tenth of the stream rate


def test_an_unanswered_request_moves_on_after_ack_timeout() -> None:
    v, req = Vehicle(), StreamRequest(rate=4.0, ack_timeout=0.5)
    req.step(v, TARGET, 0.0)
    ack(v, mav.MAV_RESULT_ACCEPTED)
    req.step(v, TARGET, 0.1)  # the second, never answered
    assert req.step(v, TARGET, 0.55) == []
    assert only(req.step(v, TARGET, 0.6)).param1 == getattr(mav, f"MAVLINK_MSG_ID_{STREAMS[2][0]}")


def test_old_firmware_gets_request_data_stream() -> None:
    for answer in (mav.MAV_RESULT_UNSUPPORTED, mav.MAV_RESULT_DENIED, None):
        v, req = Vehicle(), StreamRequest(rate=4.4, ack_timeout=0.5)
        req.step(v, TARGET, 0.0)
        if answer is not None:
            ack(v, answer)
        msgs = req.step(v, TARGET, 1.0)
        assert req.done and [m.req_stream_id for m in msgs] == list(DATA_STREAMS)
        assert {m.req_message_rate for m in msgs} == {4} and {m.start_stop for m in msgs} == {1}
        assert req.step(v, TARGET, 2.0) == []


def test_a_later_refusal_is_no_fallback() -> None:
    v, req = Vehicle(), StreamRequest(rate=10.0, ack_timeout=0.5)
    req.step(v, TARGET, 0.0)
    ack(v, mav.MAV_RESULT_ACCEPTED)
    req.step(v, TARGET, 0.1)
    ack(v, mav.MAV_RESULT_UNSUPPORTED)  # ATTITUDE refused: the rest are still asked for
    assert only(req.step(v, TARGET, 0.2)).param1 == mav.MAVLINK_MSG_ID_VFR_HUD and not req.done
