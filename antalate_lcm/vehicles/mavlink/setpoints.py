"""When a velocity set-point may go to ArduCopter, and when it is resent (pure, no I/O, time passed in).

ArduCopter forgets a velocity target after GUID_TIMEOUT (3 s), so the adapter resends the current one.
The rules below come from a field trial in which a TCP link flushed its backlog after a cut and the
copter flew 6.1 m while the HLC said LLC_DOWN (docs/ardupilot.md, "Velocity set-points"):

* never a set-point older than ``setpoint_timeout`` (counted from the HLC's `set_velocity` call);
* never into a stale link (nothing heard from the vehicle for ``link_stale_after``), and when messages
  flow again after a stale spell, a zero set-point at once, right behind any backlog;
* only while the copter flies in GUIDED (armed, GUIDED, in the air);
* no zero set-point during the takeoff climb: any new target ends the takeoff in GUIDED, and the HLC's
  "hover once airborne" would stop the climb a little short; a zero set-point is resent for
  `ZERO_RESEND` s only (against a lost datagram), then ArduCopter holds position by itself.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.mavlink.dialect import FRAMES
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle

ZERO_RESEND = 1.0  # s a zero (hover) set-point is still resent, against a lost datagram


@dataclass
class Setpoint:
    """The last velocity target, kept for the resend."""

    frame: int  # MAV_FRAME_*
    vx: float
    vy: float
    vz: float
    yaw_rate: float  # deg/s, clockwise, like every yaw rate in antalate; rad/s only on the wire
    set_at: float  # time of the set_velocity() call: the set-point's age counts from here
    next_send: float  # when the resend is due

    @property
    def zero(self) -> bool:
        return self.vx == 0.0 and self.vy == 0.0 and self.vz == 0.0 and self.yaw_rate == 0.0


class Verdict(enum.Enum):
    """What becomes of a new set-point."""

    SEND = "send"  # send it now (and keep resending it, if the resend is on)
    IGNORE = "ignore"  # not in GUIDED flight, or a zero during the takeoff climb: nothing to send or keep
    WITHHOLD = "withhold"  # the link is stale: it would wait in a buffer and fly when the link returns


@dataclass(frozen=True)
class SetpointRules:
    """The limits from ``[hlc.autopilot_params]``: resend period (0 = no resend), age limit, staleness."""

    resend_period: float
    timeout: float
    stale_after: float

    def stale(self, vehicle: Vehicle, now: float) -> bool:
        """Nothing heard from the vehicle for ``stale_after`` (or nothing at all yet)."""
        return vehicle.rx_at is None or now - vehicle.rx_at > self.stale_after

    def new(self, frame: Frame, vx: float, vy: float, vz: float, yaw_rate: float, now: float) -> Setpoint:
        return Setpoint(FRAMES[Frame(frame)], vx, vy, vz, yaw_rate, now, now + self.resend_period)

    def judge(self, vehicle: Vehicle, sp: Setpoint, now: float) -> Verdict:
        """A set-point from the HLC at `now`: send it, ignore it, or withhold it from a stale link."""
        if not (vehicle.armed and vehicle.mode == "GUIDED"):
            return Verdict.IGNORE  # ArduCopter ignores targets outside GUIDED: nothing to keep alive
        if self.stale(vehicle, now):
            return Verdict.WITHHOLD
        if sp.zero and vehicle.landed_state == mav.MAV_LANDED_STATE_TAKEOFF:
            return Verdict.IGNORE  # let the takeoff finish; it ends in a hover anyway
        return Verdict.SEND

    def keep(self, sp: Setpoint) -> Setpoint | None:
        """The set-point to keep resending after it was sent (None without a resend)."""
        return sp if self.resend_period > 0 else None

    def due(self, vehicle: Vehicle, sp: Setpoint | None, now: float) -> tuple[Setpoint | None, Verdict]:
        """The resend at `now`: (the set-point still kept, SEND if it goes out now).

        An expired set-point, or one that no longer applies (the copter left GUIDED flight), is dropped
        (IGNORE); one due while the link is stale is dropped and WITHHOLD says so (never queue a
        set-point into a cut link). `sp.next_send` moves on when it goes out.
        """
        if sp is None or now < sp.next_send:
            return sp, Verdict.IGNORE
        hold = min(ZERO_RESEND, self.timeout) if sp.zero else self.timeout
        if now - sp.set_at >= hold or not vehicle.flying_guided:
            return None, Verdict.IGNORE
        if self.stale(vehicle, now):
            return None, Verdict.WITHHOLD
        sp.next_send = max(sp.next_send + self.resend_period, now)
        return sp, Verdict.SEND

    def stop_after_stale(self, vehicle: Vehicle, now: float) -> Setpoint | None:
        """Called with a message that just arrived, before the vehicle takes it: the zero set-point to send
        at once if the link was stale while the copter flew in GUIDED (whatever we wrote before noticing
        may be flushed to the vehicle right now; a stop sent at once arrives right behind it)."""
        if self.stale(vehicle, now) and vehicle.flying_guided:
            return self.new(Frame.NED, 0.0, 0.0, 0.0, 0.0, now)
        return None
