"""The Tello adapter's control thread: ``rc`` at ``control_hz``, keepalives, and the landings it starts.

A fixed schedule (rc goes out at that rate and no other) streams ``rc`` while a velocity set-point,
the take-off climb (`maths.climb_done`) or the RTL leg is active, and sends ``rc 0 0 0 0`` every
``keepalive_s`` whenever the Tello is in the air and not landing -- also while a command waits for
its answer -- because a Tello lands itself 15 s after the last command (SDK 3.0 user guide, "Safety
Function"). While the link is lost it sends what `failsafe.Failsafes` allows: one hover, then
``command`` probes.
"""

from __future__ import annotations

import logging

from antalate_lcm.vehicles.base import AutopilotError, Frame
from antalate_lcm.vehicles.tello import maths
from antalate_lcm.vehicles.tello.commands import CommandChannel
from antalate_lcm.vehicles.tello.failsafe import Failsafes
from antalate_lcm.vehicles.tello.flight import TelloPhase
from antalate_lcm.vehicles.tello.landing import Lander
from antalate_lcm.vehicles.tello.maths import RC
from antalate_lcm.vehicles.tello.params import Params
from antalate_lcm.vehicles.tello.parts import Part, Shared
from antalate_lcm.vehicles.tello.rtl import ReturnHome
from antalate_lcm.vehicles.tello.tracking import PacketTracker

log = logging.getLogger("antalate.autopilot.tello")

_STOP_REPEAT = 3  # zero rc sent this many ticks in a row when motion stops (UDP may drop one)


class Sticks:
    """Velocities as ``rc`` stick values, scaled by ``max_speed``, ``max_vertical_speed``, ``max_yaw_rate``."""

    def __init__(self, p: Params, track: PacketTracker) -> None:
        self._p = p
        self._track = track

    def __call__(self, fwd: float, right: float, up: float, yaw_rate: float) -> RC:
        """Body frame: forward, right, up (m/s) and yaw rate (deg/s)."""
        p = self._p
        return maths.rc_sticks(
            fwd,
            right,
            up,
            yaw_rate,
            max_speed=p.max_speed,
            max_vertical_speed=p.max_vertical_speed,
            max_yaw_rate=p.max_yaw_rate,
        )

    def ned(self, vn: float, ve: float, up: float, yaw_rate: float) -> RC:
        """North and east (m/s), rotated into the body frame by the Tello's heading now."""
        fwd, right = maths.ne_to_body(vn, ve, self._track.heading())
        return self(fwd, right, up, yaw_rate)


class ControlLoop(Part):
    """The thread's loop (`run`) and what each tick sends (`lock` held while deciding, not sending)."""

    def __init__(
        self,
        shared: Shared,
        commands: CommandChannel,
        *,
        failsafes: Failsafes,
        rtl: ReturnHome,
        lander: Lander,
        sticks: Sticks,
    ) -> None:
        super().__init__(shared)
        self._commands = commands
        self._failsafes = failsafes
        self._rtl = rtl
        self._lander = lander
        self._sticks = sticks
        self._stop_ticks = 0  # zero rc still to send after motion stopped

    def run(self) -> None:
        """Tick at ``control_hz`` on a fixed schedule (a late tick does not delay the next ones)."""
        period = 1.0 / self._p.control_hz
        due = self._clock()
        while True:
            due += period
            delay = due - self._clock()
            if delay < -period:  # fell behind (a stalled machine): restart the schedule, no burst
                due = self._clock()
                delay = 0.0
            if self._stop.wait(max(0.0, delay)):
                return
            try:
                self._tick()
            except AutopilotError as exc:
                self._ratelog.log(("tick", str(exc)), logging.WARNING, "Tello %s: %s", self._host, exc)
            except Exception:  # noqa: BLE001 - the thread must outlive a bug in one tick
                log.exception("Tello %s control tick failed", self._host)

    def _tick(self) -> None:
        now = self._clock()
        land = probe = False
        f = self._flight
        with self._lock:
            self._failsafes.ingest()
            rc = self._tick_rc(now)
            if self._failsafes.silenced:
                probe = self._failsafes.probe_due(now)
            elif f.phase is TelloPhase.LAND and f.land_due is not None and now >= f.land_due:
                f.land_due = None
                land = True
        if rc is not None:
            self._commands.send_rc(rc)
        if probe:
            self._commands.probe()
        if land:
            self._lander.in_background()

    def _tick_rc(self, now: float) -> RC | None:
        """What to send this tick (lock held): streaming rc, a stop, a keepalive, or nothing."""
        p, f = self._p, self._flight
        lost, hover = self._failsafes.link_lost(now)
        if lost:
            return hover
        if self._failsafes.unattended(now):
            return (0, 0, 0, 0)
        phase = f.phase
        rc: RC | None = None
        if phase is TelloPhase.TAKEOFF and f.climb_target is not None:
            rc = self._climb_rc(f.climb_target)
        elif phase is TelloPhase.RTL:
            leg = self._rtl.leg(now)
            rc = (0, 0, 0, 0) if leg is None else self._sticks.ned(*leg, 0.0, 0.0)
        elif phase is TelloPhase.GUIDED and f.setpoint is not None:
            if now - f.setpoint_time <= p.velocity_hold:
                rc = self._setpoint_rc()
            else:
                f.setpoint = None
        if rc is not None:
            self._stop_ticks = _STOP_REPEAT if any(rc) else 0
            return rc
        if self._stop_ticks > 0 and phase is not TelloPhase.LAND:
            self._stop_ticks -= 1
            return (0, 0, 0, 0)
        if (
            phase is not TelloPhase.LAND
            and self._track.in_air()
            and now - self._commands.last_sent >= p.keepalive_s
        ):
            return (0, 0, 0, 0)  # also while a takeoff or up waits for its answer
        return None

    def _climb_rc(self, target: float) -> RC:
        height = self._track.reading.height
        speed = maths.climb_speed(height, target, self._p.max_vertical_speed)
        if speed == 0.0:
            log.info("Tello %s reached %.2f m (target %.2f m)", self._host, height, target)
            self._flight.climb_target = None
            self._flight.phase = TelloPhase.GUIDED
            return (0, 0, 0, 0)
        return self._sticks(0.0, 0.0, speed, 0.0)

    def _setpoint_rc(self) -> RC:
        """The set-point as rc, recomputed each tick so a NED set-point stays NED while yawing."""
        assert self._flight.setpoint is not None
        vx, vy, vz, yaw_rate, frame = self._flight.setpoint
        if frame is Frame.BODY:
            return self._sticks(vx, vy, -vz, yaw_rate)
        return self._sticks.ned(vx, vy, -vz, yaw_rate)
