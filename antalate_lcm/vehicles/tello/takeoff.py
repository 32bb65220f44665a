"""The Tello's take-off to an altitude, which its own ``takeoff`` does not do.

The Tello's ``takeoff`` stops at about 0.8 m. With ``takeoff_altitude_mode = "rc"`` (default)
`Takeoff.fly` returns once that is done and the control thread climbs (or descends) with ``rc`` until
`maths.climb_done`: the reading at or above the target (`base.altitude_reached` at fraction 1, so the
HLC's ``airborne_fraction`` test holds whatever it is) and at most a decimetre above it. With ``"up"``
it also sends ``up``/``down`` and returns only at the altitude. A lost ``ok`` is settled by the state
packets: the Tello in the air and holding its height.
"""

from __future__ import annotations

import logging
import time

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.tello import maths
from antalate_lcm.vehicles.tello.commands import POLL, CommandChannel, Preempted
from antalate_lcm.vehicles.tello.flight import TelloPhase
from antalate_lcm.vehicles.tello.parts import Part, Shared

log = logging.getLogger("antalate.autopilot.tello")

_SETTLED = 1.0  # s of unchanged height (and zero vertical speed) that end a take-off or up/down
_UP_MIN_CM, _UP_MAX_CM = 20, 500  # the SDK's range for up/down


class Takeoff(Part):
    """`fly` is the HLC's `takeoff` after the link check; it takes the adapter's lock itself."""

    def __init__(self, shared: Shared, commands: CommandChannel) -> None:
        super().__init__(shared)
        self._commands = commands

    def fly(self, alt: float) -> None:
        """``takeoff``, then the climb to `alt` (handed to the control thread, or by ``up``/``down``)."""
        f, track, cmd = self._flight, self._track, self._commands
        with self._lock:
            if f.phase is not TelloPhase.GROUND or track.in_air():
                raise AutopilotError(
                    f"takeoff refused: already {f.phase.value.lower()} at {track.reading.height:.1f} m"
                )
            f.commanded()
            f.phase = TelloPhase.TAKEOFF
            f.takeoff_point = (track.north, track.east)
            f.hold()
            f.failsafe = ""
            cmd.owed = None
            sent = self._clock()
        try:
            answer = cmd.exchange(
                "takeoff", self._p.takeoff_timeout, settled=self._move_settled, done_in_air=True
            )
        except Preempted:
            raise AutopilotError("takeoff interrupted (land, rtl or emergency)") from None
        except AutopilotError:
            self._failed()
            raise
        if answer not in ("ok", ""):
            self._failed()
            raise AutopilotError(f"the Tello at {self._host} refused 'takeoff': {answer!r}")
        with self._lock:
            track.air.reset(True)  # it said so (or the packets did): no half second of doubt
            if not answer:  # its "ok" may still come (DJITelloPy #31: > 7 s), or was lost
                cmd.owed = ("takeoff", sent + self._p.takeoff_timeout)
        if not answer:
            log.warning(
                "Tello %s: no answer to 'takeoff', but the state shows it up at %.1f m: going on",
                self._host,
                track.reading.height,
            )
        if self._p.takeoff_altitude_mode == "up":
            try:
                self._climb_with_up(alt)
            except Preempted:
                raise AutopilotError("climb interrupted (land, rtl or emergency)") from None
        else:
            self._wait_fresh_state()  # the height when "ok" came, not from a packet sent mid-climb
        with self._lock:
            if f.phase is TelloPhase.TAKEOFF:
                if maths.climb_done(track.reading.height, alt):
                    f.phase = TelloPhase.GUIDED
                else:
                    f.climb_target = alt  # the control thread takes it from here

    def _failed(self) -> None:
        with self._lock:
            if self._flight.phase is TelloPhase.TAKEOFF:
                self._flight.phase = TelloPhase.GUIDED if self._track.in_air() else TelloPhase.GROUND

    def _move_settled(self) -> bool:
        """A take-off or up/down whose answer was lost is over (lock held): flying, height steady.

        Timed from when the command went out (`CommandChannel.sent_at`), not from the call: a wait for
        an owed answer may come first, hovering, and that hover is not this move settling.
        """
        now = self._clock()
        track = self._track
        return (
            track.air.value
            and now - self._commands.sent_at >= _SETTLED
            and now - track.height_changed >= _SETTLED
            and abs(track.reading.vd) < 0.05
        )

    def _climb_with_up(self, alt: float) -> None:
        """``takeoff_altitude_mode = "up"``: blocking up/down until the climb is done (or 20 cm short)."""
        for _ in range(4):
            self._wait_fresh_state()
            with self._lock:
                height = self._track.reading.height
                delta = alt + maths.CLIMB_BAND / 2.0 - height
                if maths.climb_done(height, alt):
                    return
            cm = max(_UP_MIN_CM, round(abs(delta) * 100))
            answer = self._commands.exchange(
                f"{'up' if delta > 0 else 'down'} {min(cm, _UP_MAX_CM)}",
                self._p.takeoff_timeout,
                settled=self._move_settled,
                done_in_air=True,
            )
            if answer not in ("ok", ""):
                raise AutopilotError(f"the Tello at {self._host} refused the climb: {answer!r}")

    def _wait_fresh_state(self, timeout: float = 0.5) -> None:
        """Until a state packet newer than the call arrives (or `timeout` s, all on the adapter's clock)."""
        start = self._clock()
        while self._clock() - start < timeout:
            with self._lock:
                self._ingest()
                heard_at = self._track.age.heard_at
                if heard_at is not None and heard_at > start:
                    return
            time.sleep(POLL)
