"""Asking ArduCopter for the telemetry the adapter needs, one request at a time (pure, time passed in).

MAV_CMD_SET_MESSAGE_INTERVAL goes out for one message after the other, each matched to its COMMAND_ACK
(they all share one command id, so only one may be in flight). When the first is refused or never
answered, the firmware is too old for it: REQUEST_DATA_STREAM asks for the same messages by group.

`StreamRequest.step` says what to send now; whoever owns the link sends it. `connect` steps it and
waits for each answer; after a reboot or a reopened link the transmit thread steps it between its
heartbeats, so reception never waits on a request and no thread is started for one.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.mavlink import dialect
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle

log = logging.getLogger("antalate.autopilot.mavlink")

_FALLBACK = (None, mav.MAV_RESULT_UNSUPPORTED, mav.MAV_RESULT_DENIED)


@dataclass
class StreamRequest:
    """One round of telemetry requests at ``rate`` Hz; an answer counts within ``ack_timeout`` s."""

    rate: float
    ack_timeout: float
    index: int = 0  # the STREAMS entry asked for, or about to be
    mark: int = -1  # `Vehicle.messages` when it went out (-1: not yet sent)
    sent_at: float = -math.inf
    done: bool = False

    @property
    def deadline(self) -> float:
        """When the request in flight counts as unanswered."""
        return self.sent_at + self.ack_timeout

    def answered(self, vehicle: Vehicle) -> bool:
        return self.mark >= 0 and vehicle.ack_after(mav.MAV_CMD_SET_MESSAGE_INTERVAL, self.mark) is not None

    def step(self, vehicle: Vehicle, target: tuple[int, int], now: float) -> list[Any]:
        """The messages to send at `now` (often none: the request in flight is still waiting)."""
        if self.done:
            return []
        if self.mark >= 0:
            result = vehicle.ack_after(mav.MAV_CMD_SET_MESSAGE_INTERVAL, self.mark)
            if result is None and now < self.deadline:
                return []
            name = dialect.STREAMS[self.index][0]
            if self.index == 0 and result in _FALLBACK:
                log.info(
                    "SET_MESSAGE_INTERVAL %s (%s): falling back to REQUEST_DATA_STREAM",
                    dialect.result_name(result).lower(),
                    name,
                )
                self.done = True
                hz = max(1, round(self.rate))
                return [dialect.request_data_stream(target, stream, hz) for stream in dialect.DATA_STREAMS]
            if result != mav.MAV_RESULT_ACCEPTED:
                log.debug("SET_MESSAGE_INTERVAL %s: %s", name, dialect.result_name(result))
            self.index += 1
            if self.index == len(dialect.STREAMS):
                self.done = True
                return []
        name, factor = dialect.STREAMS[self.index]
        self.mark, self.sent_at = vehicle.messages, now
        msg_id = getattr(mav, f"MAVLINK_MSG_ID_{name}")
        interval_us = 1e6 / (self.rate * factor)
        return [dialect.command_long(target, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, interval_us)]
