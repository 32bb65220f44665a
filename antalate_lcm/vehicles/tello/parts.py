"""What the Tello adapter's parts share: one `Shared` made by the adapter, one `Part` base that keeps it.

Every part (the command channel, the failsafes, the control loop, the moves) works on the same
picture of the Tello (`tracking.PacketTracker`), the same phase (`flight.Flight`) and the same lock,
which the adapter's own calls hold too: the parts are the adapter's responsibilities, not separate
actors, so they share its state rather than copy it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.vehicles.base import Clock
from antalate_lcm.vehicles.tello.flight import Flight
from antalate_lcm.vehicles.tello.link import TelloLink
from antalate_lcm.vehicles.tello.params import Params
from antalate_lcm.vehicles.tello.tracking import PacketTracker


@dataclass(frozen=True, slots=True)
class Shared:
    """The adapter's state and hooks, as each part sees them."""

    p: Params
    clock: Clock
    host: str
    lock: threading.RLock  # the adapter's state lock: `track` and `flight` are read and written under it
    stop: threading.Event  # set while the adapter closes: every loop and wait ends on it
    ratelog: RateLimitedLog
    link: Callable[[], TelloLink | None]  # the open link, None before connect and after close
    ingest: Callable[[], None]  # take in the newest state packet and react to it (lock held)
    track: PacketTracker
    flight: Flight


class Part:
    """Base of the adapter's parts: `Shared`'s fields as attributes of the part."""

    def __init__(self, shared: Shared) -> None:
        self._p = shared.p
        self._clock = shared.clock
        self._host = shared.host
        self._lock = shared.lock
        self._stop = shared.stop
        self._ratelog = shared.ratelog
        self._link = shared.link
        self._ingest = shared.ingest
        self._track = shared.track
        self._flight = shared.flight
