"""The Tello's return-to-launch, which it has not got: fly back to the take-off point with ``rc``, land.

The leg is flown by the control thread at ``rtl_speed`` (slowing near the point) on the dead-reckoned
position. `TelloAdapter.rtl` returns once the distance is shrinking (a few seconds at most) or
raises `AutopilotError` when it grows or does not shrink (a wrong sign convention or heading): the
Tello then lands where it is, and the HLC reports the reason as an ``hlc_error_t``. Later failures of
the leg (it grows by ``2 m``, or it takes far longer than it should) also land it where it is, with
the reason in ``VehicleState.failsafe``.
"""

from __future__ import annotations

import logging
import time

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.tello import maths
from antalate_lcm.vehicles.tello.flight import TelloPhase
from antalate_lcm.vehicles.tello.parts import Part

log = logging.getLogger("antalate.autopilot.tello")

_APPROACH_GAIN = 1.0  # 1/s: RTL speed per metre of remaining distance (below rtl_speed)
_MIN_APPROACH_SPEED = 0.2  # m/s
_RTL_DIVERGENCE = 2.0  # m: farther than the start distance by this much during the leg -> land here
_RTL_PROGRESS = 0.5  # m: rtl() returns once the distance shrank by this (or by half, when shorter)
_RTL_EARLY_DIVERGENCE = 0.5  # m: rtl() fails when the distance grew by this before shrinking


class ReturnHome(Part):
    """The RTL leg: its start, its velocity each control tick, its check and its abort.

    `start`, `leg` and `abort` run with the adapter's lock held, `verify` takes it itself.
    """

    def start(self) -> float:
        """Begin the leg from here (the HLC's `rtl`): the distance to go; raises when it cannot be trusted."""
        f = self._flight
        f.hold()
        f.failsafe = ""
        if self._track.units.problem:
            # home is where dead reckoning says, and it is not to be believed: land here
            reason = f"dead reckoning unreliable ({self._track.units.problem}); landing here"
            self.abort(reason)
            raise AutopilotError(reason)
        f.phase = TelloPhase.RTL
        f.rtl_start = self._clock()
        f.rtl_dist0 = dist0 = self._track.distance_to(f.takeoff_point)
        log.info("Tello %s RTL: %.1f m to the take-off point", self._host, dist0)
        return dist0

    def leg(self, now: float) -> tuple[float, float] | None:
        """This tick's velocity north/east, or None to stop (arrived: landing; or aborted)."""
        p, f = self._p, self._flight
        vn, ve, dist = maths.rtl_leg(
            self._track.north,
            self._track.east,
            f.takeoff_point,
            speed=p.rtl_speed,
            gain=_APPROACH_GAIN,
            min_speed=_MIN_APPROACH_SPEED,
        )
        deadline = 10.0 + 3.0 * f.rtl_dist0 / p.rtl_speed
        if dist <= p.rtl_tolerance:
            log.info("Tello %s RTL: at the take-off point (%.2f m): landing", self._host, dist)
            f.phase = TelloPhase.LAND
            f.land_due = now  # the control thread lands (outside the state lock)
            return None
        if dist > f.rtl_dist0 + _RTL_DIVERGENCE:
            self.abort(
                f"getting farther ({dist:.1f} m, started at {f.rtl_dist0:.1f} m): check "
                "vgx_sign, vgy_sign, velocity_frame and home_heading; landing here"
            )
            return None
        if now - f.rtl_start > deadline:
            self.abort(f"not back after {deadline:.0f} s ({dist:.1f} m to go): landing here")
            return None
        return vn, ve

    def verify(self, dist0: float) -> None:
        """Wait until the RTL leg is seen closing in; raise (and land here) when it is not."""
        p, f = self._p, self._flight
        progress = min(_RTL_PROGRESS, dist0 / 2.0)
        deadline = self._clock() + 1.0 + 3.0 * _RTL_PROGRESS / p.rtl_speed
        while True:
            with self._lock:
                self._ingest()
                if f.phase is not TelloPhase.RTL:
                    if f.failsafe:  # the control thread gave up first (the HLC prefixes "RTL failed")
                        raise AutopilotError(f.failsafe.removeprefix("RTL failed: "))
                    return  # arrived (landing) or overtaken by a land/emergency
                dist = self._track.distance_to(f.takeoff_point)
                if dist <= p.rtl_tolerance or dist <= dist0 - progress:
                    return
                reason = ""
                if dist > dist0 + _RTL_EARLY_DIVERGENCE:
                    reason = (
                        f"getting farther ({dist:.1f} m, started at {dist0:.1f} m): check vgx_sign, "
                        "vgy_sign, velocity_frame and home_heading; landing here"
                    )
                elif self._clock() >= deadline:
                    reason = (
                        f"not getting closer ({dist:.1f} m, started at {dist0:.1f} m) after "
                        f"{deadline - f.rtl_start:.0f} s; landing here"
                    )
                if reason:
                    self.abort(reason)
                    break
            time.sleep(0.05)
        raise AutopilotError(reason)  # the HLC reports "autopilot RTL failed: <reason>"

    def abort(self, reason: str) -> None:
        """End the RTL where the Tello is: land here, and say why."""
        log.warning("Tello %s RTL: %s", self._host, reason)
        f = self._flight
        f.failsafe = f"RTL failed: {reason}"
        f.phase = TelloPhase.LAND
        f.land_due = self._clock()  # the control thread lands (outside the state lock)
