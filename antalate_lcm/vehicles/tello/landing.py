"""Landing the Tello: ``land`` once, settled by its answer or by the state packets, retried in the air.

``land`` is answered ``ok`` once the Tello is down, but the answer may be lost, or be a late answer to
something else; the state packets settle it either way, and until they show the Tello on the ground
the HLC sees the landing in progress.
"""

from __future__ import annotations

import logging
import threading

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.tello.commands import CommandChannel
from antalate_lcm.vehicles.tello.flight import TelloPhase
from antalate_lcm.vehicles.tello.parts import Part, Shared

_LAND_RETRY = 2.0  # s between attempts when a land command failed in the air


class Lander(Part):
    """``land`` from the HLC's thread (`land_now`) or a thread of its own (`in_background`)."""

    def __init__(self, shared: Shared, commands: CommandChannel) -> None:
        super().__init__(shared)
        self._commands = commands
        self._thread: threading.Thread | None = None

    def landed(self) -> bool:
        """The state packets have shown the Tello on the ground for `GROUND_CONFIRM` (lock held)."""
        return not self._track.air.value and not self._track.in_air()

    def land_now(self) -> None:
        """Send ``land`` unless the Tello is already down; settled by its answer or by the state packets.

        The check is made holding the command lock, so when the HLC's `land` and the end of an RTL
        meet, the second finds the Tello on the ground instead of sending a second ``land``. On a
        failure in the air the control thread retries.
        """
        f = self._flight
        with self._commands.cmd_lock:
            with self._lock:
                self._ingest()
                if f.phase is not TelloPhase.LAND:
                    return
                if self.landed():
                    f.phase = TelloPhase.GROUND
                    return
            try:
                answer = self._commands.exchange(
                    "land", self._p.takeoff_timeout, settled=self.landed, preemptible=False
                )
            except AutopilotError:
                answer = "no answer"
        with self._lock:
            if f.phase is not TelloPhase.LAND:
                return  # emergency, or the Tello was seen on the ground meanwhile
            if answer == "ok" and not self._track.in_air():
                self._track.air.reset(False)  # down, by its answer and the newest packet
            if answer == "ok" or self.landed():
                # "ok" comes once it is down; the next packets say so, and until they have the HLC
                # sees the landing still in progress (state() keeps in_air while LAND). Should they
                # never say so (an "ok" that answered something else), land is sent again.
                f.land_due = self._clock() + 2.0 * _LAND_RETRY
                if self.landed():
                    f.phase = TelloPhase.GROUND
                return
            f.land_due = self._clock() + _LAND_RETRY
        raise AutopilotError(
            f"the Tello at {self._host} did not land ({answer!r}); retrying every {_LAND_RETRY:g} s"
        )

    def in_background(self) -> None:
        """Land from a thread of its own, so the control thread keeps its rc schedule."""
        if self._thread is not None and self._thread.is_alive():
            return

        def run() -> None:
            try:
                self.land_now()
            except AutopilotError as exc:
                self._ratelog.log(("land", str(exc)), logging.WARNING, "Tello %s: %s", self._host, exc)

        self._thread = threading.Thread(target=run, name=f"tello-land-{self._host}", daemon=True)
        self._thread.start()
