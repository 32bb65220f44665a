"""When a velocity set-point goes to PX4 in OFFBOARD, and when the adapter switches to OFFBOARD (pure).

PX4 flies OFFBOARD only while set-points keep coming: after COM_OF_LOSS_T (1 s by default) without one it
leaves OFFBOARD and runs COM_OBL_RC_ACT, and it refuses the switch unless set-points are already arriving
(src/modules/commander/Commander.cpp, ``offboardControlCheck``; src/modules/commander/
HealthAndArmingChecks/checks/offboardCheck.cpp). So, unlike ArduCopter's resend of a target that its
GUID_TIMEOUT would forget:

* the adapter streams a set-point every ``resend_period`` for as long as the vehicle flies in OFFBOARD
  (or is about to be switched there), and starts streaming ``lead`` seconds before it asks for OFFBOARD;
* the HLC's set-point is streamed until it is ``timeout`` old, then **zero** -- a stale set-point never
  flies, and the vehicle hovers in OFFBOARD under the adapter's stream instead of falling into PX4's
  offboard-loss failsafe (which is left for when antalate itself is gone or cut off);
* nothing goes into a stale link (`SetpointRules.stale`); the stream resumes with zero when it is fresh;
* BODY velocities go as MAV_FRAME_BODY_NED: PX4 1.15.4 takes only LOCAL_NED and BODY_NED (vx/vy
  rotated by its yaw, vz down) and drops anything else -- ArduCopter's BODY_OFFSET_NED included -- with
  "SET_POSITION_TARGET_LOCAL_NED coordinate frame 9 unsupported" (src/modules/mavlink/
  mavlink_receiver.cpp, ``handle_message_set_position_target_local_ned``): the real PX4 showed it, when
  the HLC's BODY-frame hover left PX4 without a valid set-point and it fell into its offboard-loss
  failsafe;
* a zero set-point never switches to OFFBOARD (PX4's Hold and the end of its take-off hover already),
  and the vehicle is only switched from a mode the adapter owns (after our take-off); a pilot's or a
  failsafe's mode is never overridden.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.mavlink.setpoints import Setpoint, SetpointRules, Verdict
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle
from antalate_lcm.vehicles.px4 import modes

#: The SET_POSITION_TARGET_LOCAL_NED frames PX4 accepts, by antalate frame (module docstring).
FRAMES: dict[Frame, int] = {Frame.NED: mav.MAV_FRAME_LOCAL_NED, Frame.BODY: mav.MAV_FRAME_BODY_NED}


def _offboard(vehicle: Vehicle) -> bool:
    return vehicle.mode == "OFFBOARD"


def _switchable(vehicle: Vehicle) -> bool:
    """Flying in a mode the adapter owns, from which it may switch to OFFBOARD."""
    return vehicle.armed and vehicle.in_air and bool(getattr(vehicle, "ours", False))


@dataclass(frozen=True)
class OffboardRules(SetpointRules):
    """`SetpointRules` for PX4: continuous streaming in OFFBOARD (module docstring); ``lead`` in s."""

    lead: float = 1.0

    def new(self, frame: Frame, vx: float, vy: float, vz: float, yaw_rate: float, now: float) -> Setpoint:
        return Setpoint(FRAMES[Frame(frame)], vx, vy, vz, yaw_rate, now, now + self.resend_period)

    def judge(self, vehicle: Vehicle, sp: Setpoint, now: float) -> Verdict:
        if not (_switchable(vehicle) and (_offboard(vehicle) or vehicle.mode == modes.HOLD)):
            return Verdict.IGNORE  # on the ground, taking off, a pilot's or a failsafe's mode
        if self.stale(vehicle, now):
            return Verdict.WITHHOLD
        if sp.zero and not _offboard(vehicle):
            return Verdict.IGNORE  # PX4's Hold already hovers: no reason to take over
        return Verdict.SEND

    def keep(self, sp: Setpoint) -> Setpoint | None:
        return sp  # always streamed: PX4 leaves OFFBOARD without it

    def due(self, vehicle: Vehicle, sp: Setpoint | None, now: float) -> tuple[Setpoint | None, Verdict]:
        if sp is None or now < sp.next_send:
            return sp, Verdict.IGNORE
        if not (_switchable(vehicle) and (_offboard(vehicle) or vehicle.mode == modes.HOLD)):
            return None, Verdict.IGNORE
        if not sp.zero and now - sp.set_at >= self.timeout:
            sp = self.hover(now)  # the HLC went quiet: never fly its last set-point on
        if self.stale(vehicle, now):
            return self.hover(now), Verdict.WITHHOLD  # resume with a stop once the link is fresh
        if sp.zero and not _offboard(vehicle):
            return None, Verdict.IGNORE
        sp.next_send = max(sp.next_send + self.resend_period, now)
        return sp, Verdict.SEND

    def stop_after_stale(self, vehicle: Vehicle, now: float) -> Setpoint | None:
        """Nothing extra: `due` keeps a zero set-point through a stale spell and streams it once the link
        is fresh (ArduCopter's one-off stop would end the stream, and PX4 would leave OFFBOARD)."""
        return None

    def hover(self, now: float) -> Setpoint:
        """A zero set-point due now (NED frame)."""
        return replace(self.new(Frame.NED, 0.0, 0.0, 0.0, 0.0, now), next_send=now)

    def switch_due(
        self, vehicle: Vehicle, sp: Setpoint | None, streaming_since: float | None, now: float
    ) -> bool:
        """Whether to ask PX4 for OFFBOARD now: a moving set-point streamed for ``lead`` s from an owned mode."""
        return (
            sp is not None
            and not sp.zero
            and streaming_since is not None
            and now - streaming_since >= self.lead
            and _switchable(vehicle)
            and not _offboard(vehicle)
            and not self.stale(vehicle, now)
        )
