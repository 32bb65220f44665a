"""`CrazyflieControl`: the control thread, the velocity stream and the high-level commander's switch.

* **Commands**: take-off, landing and the return flight go through the high-level commander, whose
  trajectories run on board and survive a lost link; MISSION velocities are streamed generic
  set-points at ``control_hz`` (the firmware levels the vehicle 0.5 s after the last one and stops its
  motors after 2 s). Leaving the stream for the high-level commander is cflib's documented switch,
  ``notify_setpoint_stop`` then a high-level command -- but never the notification alone: a stream
  stops the firmware's planner, and a stopped planner answers the notification with the null
  set-point, motors off, until a high-level command comes (crazyflie-firmware 2026.08
  crtp_commander_high_level.c ``crtpCommanderHighLevelGetSetpoint``, commander.c, PR #1298). So the
  switch is *command, notify, command* (`_switch`): whichever of the two commands arrives, the
  planner has a trajectory when the priority drops. The firmware answers every high-level packet
  (crtp_commander_high_level.c ``crtpCommanderHighLevelTask``); until the command that set the mode
  is answered, the switch is resent every ``_HL_RESEND_S`` -- also into a stale or closed link,
  so it lands as soon as the link carries it. A zero velocity, a velocity not renewed for
  ``velocity_hold`` and a link silent for ``link_stale_after`` all hand the vehicle back to the
  high-level commander holding where it is. If the switch cannot get through at all, the firmware's
  watchdog takes over: 0.5 s after the last set-point it levels the vehicle but keeps its vertical
  velocity (a climb goes on), 2 s after it stops the motors and locks (supervisor.c).
* **Link loss in the air**: after ``link_loss_land`` s the adapter sends landings blindly (a radio
  link that drops most packets still delivers some); the state then says LANDING with the failsafe
  "link lost". A Crazyflie has no link-loss failsafe of its own under the high-level commander.
  While cflib has closed the link (`connection`) the timers go on: a stream is turned into a hold and
  ``link_loss_land`` into a landing, each sent the moment the link is open again (a Crazyflie under
  the high-level commander hovers on its own meanwhile; one that was streaming has been stopped by
  the watchdog).
* **Critical battery in the air**: ``pm.vbat`` below ``critical_voltage`` for
  ``critical_land_after`` s lands the vehicle where it is (failsafe "battery critical"): a firmware
  built with ``CONFIG_PM_AUTO_SHUTDOWN`` powers off 5 s after that voltage once in lowPower
  (pm_stm32f4.c), and even without it the LiPo is empty.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Any

from antalate_lcm.vehicles.base import AutopilotError, Frame
from antalate_lcm.vehicles.crazyflie.connection import (
    _HL_GOTO,
    _HL_LAND,
    _RECONNECT_S,
    CFLIB_MISSING,
    CrazyflieConnection,
)
from antalate_lcm.vehicles.crazyflie.frames import LocalFrame
from antalate_lcm.vehicles.crazyflie.modes import HOLD, IDLE, LAND, RTL_GO, RTL_LAND, STREAM
from antalate_lcm.vehicles.crazyflie.setpoints import SetPoint, build_setpoint, goto_duration, next_height

log = logging.getLogger("antalate.autopilot.crazyflie")

__all__ = ["CrazyflieControl"]

_HL_RESEND_S = 0.3  # s without the firmware's answer to a high-level command before it is resent


class CrazyflieControl(CrazyflieConnection):
    """What the adapter is doing (``_mode``) and the thread that keeps doing it; every method under ``_lock``."""

    def _setup(self) -> None:
        super()._setup()
        p = self._p
        self.frame = LocalFrame(p.origin_lat, p.origin_lon, p.origin_heading)
        self._mode = IDLE
        self._mode_at = -math.inf
        self._failsafe = ""
        self._velocity: tuple[float, float, float, float, Frame, float] | None = None
        self._height = 0.0
        self._takeoff_alt = 0.0
        self._rtl_deadline = math.inf
        #: on the ground and not armed by us: report disarmed whatever auto-arming says (a CF2.x arms
        #: itself at power-on), and refuse a take-off that arm() did not precede
        self._ground_idle = True
        self._critical_since = math.inf
        self._blind_land_at = -math.inf
        self._blind_landing = False  # landings sent into a lost link: resent once it answers again
        self._last_tick = -math.inf

    def connect(self) -> None:
        """Open the link (`connection`), then start the control thread once."""
        try:
            import cflib  # noqa: F401
        except ImportError:
            raise AutopilotError(CFLIB_MISSING) from None
        self._open_link()
        if not self._workers.running:
            self._workers.start((self._control_loop, f"crazyflie-{self._p.uri}"))

    def _set_mode(self, mode: str) -> None:
        self._mode = mode
        self._mode_at = self.clock()

    def _leave_stream(self, cf: Any) -> None:
        """Before a high-level command: a velocity stream ends (the command's `_switch` notifies)."""
        self._velocity = None

    def _switch(self, cf: Any | None, what: str) -> None:
        """Send the high-level command `what` as *command, notify, command* and await its answer.

        Never the notification alone (the module docstring says why). `cf` None (cflib closed the
        link) only records the command: the control loop sends it once the link is open again.
        """
        cmd = {"hold": _HL_GOTO, "rtl": _HL_GOTO, "land": _HL_LAND}[what]
        self._hl_pending = (cmd, self.clock(), what)
        if cf is None:
            return
        self._send_hl(cf, what)
        cf.commander.send_notify_setpoint_stop()
        self._send_hl(cf, what)

    def _send_hl(self, cf: Any, what: str) -> None:
        r = self._reading
        if what == "hold":
            cf.high_level_commander.go_to(0.0, 0.0, 0.0, 0.0, 0.5, relative=True)
        elif what == "land":
            z = r.z if math.isfinite(r.z) else 1.0
            cf.high_level_commander.land(0.0, max(z / self._p.land_speed, 1.0), yaw=None)
        else:  # rtl: the take-off point at the current height, at rtl_speed from where it is now
            hx, hy = self._home or (0.0, 0.0)
            duration = goto_duration(math.hypot(r.x - hx, r.y - hy), self._p.rtl_speed)
            cf.high_level_commander.go_to(hx, hy, r.z, math.radians(r.yaw), duration)

    def _hold(self, cf: Any | None) -> None:
        """Back to the high-level commander, holding the current position."""
        self._leave_stream(cf)
        self._set_mode(HOLD)
        self._switch(cf, "hold")

    def _start_landing(self, cf: Any | None, mode: str) -> None:
        self._leave_stream(cf)
        self._set_mode(mode)
        self._switch(cf, "land")

    def _send_setpoint(self, cf: Any, sp: SetPoint) -> None:
        if sp.kind == "world":
            cf.commander.send_velocity_world_setpoint(*sp.values)
        else:
            cf.commander.send_hover_setpoint(*sp.values)

    def _control_loop(self) -> None:
        period = 1.0 / self._p.control_hz
        while not self._stop.wait(period):
            try:
                self._tick()
            except Exception:  # noqa: BLE001 - the control thread must outlive one bad tick
                log.exception("crazyflie control tick failed")

    def _tick(self) -> None:
        now = self.clock()
        p = self._p
        with self._lock:
            if (
                self._link_error
                and not self._connected
                and not self._reconnecting
                and not self._stop.is_set()
                and now - self._reconnect_at >= _RECONNECT_S
            ):
                self._reconnecting = True
                self._reconnect_at = now
                threading.Thread(target=self._reconnect, name="crazyflie-reconnect", daemon=True).start()
            # cflib closed the link: no cf to send on, but the timers below still run and what they
            # decide (a hold, a landing) is sent once the link is open again
            cf = self._cf if self._connected else None
            if cf is None and not self._link_error:
                return  # closing, or never opened
            dt, self._last_tick = now - self._last_tick, now
            age = self._heard()
            r = self._reading
            flying = r.flags.flying
            if self._mode == STREAM:
                if cf is None or age > p.link_stale_after:
                    log.warning("link %.1f s old: the high-level commander holds the Crazyflie", age)
                    self._hold(cf)
                elif self._velocity is None or now - self._velocity[5] > p.velocity_hold:
                    self._hold(cf)
                else:
                    vx, vy, vz, rate, frame, _ = self._velocity
                    if frame is Frame.BODY:
                        self._height = next_height(self._height, vz, dt)
                    self._send_setpoint(cf, build_setpoint(vx, vy, vz, rate, frame, self.frame, self._height))
            self._check_battery(cf, now, flying)
            lost = p.link_loss_land > 0 and age > p.link_loss_land
            if lost and flying and self._mode != IDLE and now - self._blind_land_at >= 1.0:
                if self._mode != LAND:
                    log.warning("link lost for %.1f s in the air: landing blindly", age)
                if not self._failsafe:
                    self._failsafe = (
                        f"link lost for more than {p.link_loss_land:g} s: the adapter commanded a landing"
                    )
                self._blind_land_at = now
                self._blind_landing = True
                self._start_landing(cf, LAND)
            elif self._blind_landing and cf is not None and age < p.link_stale_after:
                self._blind_landing = False
                if self._mode == LAND and flying:
                    log.warning("link back: the landing sent while it was lost is sent again")
                    self._start_landing(cf, LAND)
            pending = self._hl_pending
            if pending is not None and cf is not None and now - pending[1] >= _HL_RESEND_S:
                if flying:
                    log.info("no answer to the high-level %s: sent again", pending[2])
                    self._switch(cf, pending[2])
                else:
                    self._hl_pending = None
            if self._mode == RTL_GO:
                hx, hy = self._home or (0.0, 0.0)
                arrived = math.hypot(r.x - hx, r.y - hy) <= p.rtl_tolerance and math.hypot(r.vx, r.vy) < 0.05
                if arrived or now > self._rtl_deadline:
                    self._start_landing(cf, RTL_LAND)
            if (
                cf is not None
                and self._mode in (LAND, RTL_LAND)
                and not flying
                and now - self._mode_at > 0.5
                and age < p.link_stale_after
            ):
                cf.supervisor.send_arming_request(False)
                self._ground_idle = True
                self._hl_pending = None
                self._set_mode(IDLE)
                self._failsafe = ""

    def _check_battery(self, cf: Any | None, now: float, flying: bool) -> None:
        """Land where it is once ``pm.vbat`` has stayed below ``critical_voltage`` in the air."""
        p = self._p
        vbat = self._reading.vbat
        if not (math.isfinite(vbat) and vbat < p.critical_voltage):
            self._critical_since = math.inf
            return
        if math.isinf(self._critical_since):
            self._critical_since = now
        if not flying or self._mode in (IDLE, LAND) or now - self._critical_since < p.critical_land_after:
            return
        log.warning("battery critical in the air (%.2f V): landing where it is", vbat)
        self._failsafe = (
            f"battery critical: {vbat:.2f} V < {p.critical_voltage:g} V (a Crazyflie built with "
            "CONFIG_PM_AUTO_SHUTDOWN powers off 5 s later): the adapter commanded a landing"
        )
        self._start_landing(cf, LAND)
