"""`CrazyflieAdapter`: a Crazyflie through Bitcraze's cflib (docs/crazyflie.md has the operator's view).

The HLC's verbs on top of cflib. Take-off, landing and the return flight go through the high-level
commander, MISSION velocities are streamed set-points (`control`: the switch between the two, the
control thread, link-loss and battery landings); cflib's link, its log blocks and its reopening are
`connection`'s; what the adapter is doing and what the HLC sees of it, `modes`.

* **Arming** is refused, with the reason in ``last_refusal`` (and so in ``hlc_error_t``), while the
  supervisor is locked, crashed or tumbled, the estimator has not converged, ``pm.state`` says the
  battery is low, or ``pm.vbat`` is at or below ``low_voltage`` (the firmware says lowPower only
  5 s later: pm_stm32f4.c). A CF2.x arms itself (Kconfig ``MOTORS_REQUIRE_ARMING`` defaults to n;
  supervisor.c ``AUTO_ARMING``: at power-on, after a disarm, after the landed timeout), so the
  adapter's own flag decides what the HLC sees: a vehicle on the ground reads disarmed until
  `arm` and again after a landing, and `takeoff` refuses without `arm`, whatever the supervisor
  says.
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.base import (
    AutopilotError,
    Frame,
    VehicleState,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.vehicles.crazyflie.connection import _HL_TAKEOFF, CFLIB_MISSING
from antalate_lcm.vehicles.crazyflie.control import CrazyflieControl
from antalate_lcm.vehicles.crazyflie.modes import (
    FLIGHT_MODES,
    IDLE,
    LAND,
    MODE_NAMES,
    RTL_GO,
    RTL_LAND,
    STREAM,
    TAKEOFF,
)
from antalate_lcm.vehicles.crazyflie.params import Params
from antalate_lcm.vehicles.crazyflie.setpoints import (
    build_setpoint,
    goto_duration,
    is_zero,
    takeoff_duration,
)
from antalate_lcm.vehicles.crazyflie.telemetry import battery_warning, estimator_problem

log = logging.getLogger("antalate.autopilot.crazyflie")

__all__ = ["CFLIB_MISSING", "CrazyflieAdapter"]


class CrazyflieAdapter(CrazyflieControl):
    """A Crazyflie through cflib.

    The rules it keeps on top of cflib are in the docstrings of this module, `control` and `connection`.
    """

    name = "crazyflie"
    blocking = True  # arm and takeoff wait for the supervisor's confirmation over the radio
    params_model: ClassVar[type[BaseModel]] = Params

    def _setup(self) -> None:
        super()._setup()
        self.last_refusal = ""

    def _refuse(self, reason: str) -> bool:
        self.last_refusal = reason
        log.warning("arming refused: %s", reason)
        return False

    def arm(self) -> bool:
        cf = self._require_link()
        self.last_refusal = ""
        with self._lock:
            reading = self._reading
            age = self._heard()
            no_kalman = self._no_kalman
        if age > self._p.link_stale_after:
            return self._refuse(f"the link is {age:.1f} s old")
        blocker = reading.flags.arm_blocker()
        if blocker:
            return self._refuse(blocker)
        if no_kalman:
            return self._refuse(
                "kalman.varPX/PY/PZ are not in the log TOC: the pre-flight estimator check needs "
                "the Kalman estimator (stabilizer.estimator = 2)"
            )
        problem = estimator_problem(reading, self._p.max_position_variance)
        if problem:
            return self._refuse(problem)
        warning = battery_warning(reading.pm_state)
        if warning:
            return self._refuse(f"battery low: {warning}, {reading.vbat:.2f} V")
        if reading.vbat <= self._p.low_voltage:
            return self._refuse(
                f"battery low: {reading.vbat:.2f} V <= low_voltage {self._p.low_voltage:g} V "
                "(the firmware reports lowPower 5 s after it)"
            )
        with self._lock:
            self._ground_idle = False
        cf.supervisor.send_arming_request(True)
        deadline = self.clock() + self._p.arm_timeout
        while self.clock() < deadline:
            if self._reading.flags.armed:
                return True
            time.sleep(0.02)
        flags = self._reading.flags
        return self._refuse(
            f"the supervisor did not arm within {self._p.arm_timeout:g} s"
            + (
                f": {flags.arm_blocker()}"
                if flags.arm_blocker()
                else f" (supervisor.info 0x{self._reading.info:04x})"
            )
        )

    def disarm(self) -> None:
        cf = self._require_link()
        cf.supervisor.send_arming_request(False)
        with self._lock:
            self._ground_idle = True

    def takeoff(self, alt: float) -> None:
        check_takeoff_altitude(alt)
        cf = self._require_link()
        with self._lock:
            r = self._reading
            if not r.flags.armed or self._ground_idle:
                raise AutopilotError("not armed")
            if r.flags.flying and self._mode != IDLE:
                # planner.c plan_takeoff answers 1 unless its planner is idle; worse, mid-stream the
                # stream has stopped the planner, which would take it while the stream's priority
                # stays up and the stream ends: the watchdog's cut 2 s later
                raise AutopilotError(
                    f"takeoff refused: the Crazyflie is flying ({MODE_NAMES[self._mode]}); "
                    "its planner takes off only when idle: land first"
                )
            self._leave_stream(cf)
            self._hl_pending = None
            mode0, home0 = self._mode, self._home
            self._home = (r.x, r.y)
            self._set_mode(TAKEOFF)
            self._takeoff_alt = alt
            self._failsafe = ""
            self._hl_refused = None
            self._takeoff_accepted = False
            z0 = r.z
            was_flying = r.flags.flying
        cf.high_level_commander.takeoff(alt, takeoff_duration(z0, alt, self._p.climb_speed), yaw=None)
        deadline = self.clock() + self._p.takeoff_confirm
        while self.clock() < deadline:
            r = self._reading
            refused = self._hl_refused if self._hl_refused and self._hl_refused[0] == _HL_TAKEOFF else None
            # Lifting, or flying by the firmware's word -- but a flying bit already set when the
            # command went (a hover, a landing still running) is no take-off: the planner refuses
            # one unless idle (planner.c plan_takeoff) and only its answer says which.
            flying = r.flags.flying and (not was_flying or self._takeoff_accepted)
            if refused is None and (flying or r.z > z0 + 0.05):
                return
            if refused is not None:
                with self._lock:  # what it was doing goes on (a hover, a landing)
                    self._set_mode(mode0 if was_flying else IDLE)
                    self._home = home0 if was_flying else self._home
                raise AutopilotError(
                    "the Crazyflie refused the take-off: "
                    + (
                        "its supervisor cannot fly (EBUSY: not armed, locked or crashed)"
                        if refused[1] == 16
                        else f"its planner is busy with a trajectory or a landing (result {refused[1]})"
                    )
                )
            time.sleep(0.02)
        with self._lock:
            self._set_mode(mode0 if was_flying else IDLE)
        blocker = self._reading.flags.arm_blocker()
        raise AutopilotError(
            f"the Crazyflie did not take off within {self._p.takeoff_confirm:g} s: "
            + (blocker or "the supervisor never reported flying")
        )

    def land(self) -> None:
        cf = self._require_link()
        with self._lock:
            self._start_landing(cf, LAND)

    def rtl(self) -> None:
        cf = self._require_link()
        with self._lock:
            r = self._reading
            self._leave_stream(cf)
            if self._home is None:
                log.warning(
                    "RTL with no take-off point known (connected in the air): returning to the origin"
                )
                self._home = (0.0, 0.0)
            hx, hy = self._home
            distance = math.hypot(r.x - hx, r.y - hy)
            if distance <= self._p.rtl_tolerance:
                self._start_landing(cf, RTL_LAND)
                return
            duration = goto_duration(distance, self._p.rtl_speed)
            self._set_mode(RTL_GO)
            self._rtl_deadline = self.clock() + duration + 5.0
            self._switch(cf, "rtl")
        log.info("RTL: go_to the take-off point (%.2f, %.2f), %.1f m in %.1f s", hx, hy, distance, duration)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        check_velocity(vx, vy, vz, yaw_rate)
        cf = self._require_link()
        with self._lock:
            if self._mode in (LAND, RTL_GO, RTL_LAND):
                return  # a hover (or a late set-point) never cancels a landing or the way home
            if is_zero(vx, vy, vz, yaw_rate):
                self._velocity = None
                if self._mode == STREAM:
                    self._hold(cf)
                return
            if not self._reading.flags.flying:
                raise AutopilotError("not flying: velocity set-points are for the air")
            if self._mode != STREAM:
                # the HLC steers from 95 % of the take-off altitude: a body-frame height target
                # started during the climb still ends at the altitude asked for
                z = self._reading.z
                self._height = max(z, self._takeoff_alt) if self._mode == TAKEOFF else z
                self._set_mode(STREAM)
                self._hl_pending = None  # the stream supersedes a hold or a landing not yet answered
            self._velocity = (vx, vy, vz, yaw_rate, Frame(frame), self.clock())
            self._send_setpoint(
                cf, build_setpoint(vx, vy, vz, yaw_rate, Frame(frame), self.frame, self._height)
            )

    # ------------------------------------------------------------------ state
    def state(self) -> VehicleState:
        with self._lock:
            r = self._reading
            connected = self._connected and self._cf is not None
            age = self._heard()
            mode = self._mode
            failsafe = self._failsafe
            ground_idle = self._ground_idle
        flags = r.flags
        common: dict[str, Any] = {
            "connected": connected,
            "link_age": age,
            "battery": float(r.battery_level) if r.battery_level >= 0 else -1.0,
            "voltage": r.vbat,
            "cells": self._p.cells,
            "battery_warning": battery_warning(r.pm_state),
            "armed": flags.armed and not (ground_idle and not flags.flying),
            "in_air": flags.flying,
            "mode": "LOCKED" if flags.locked else MODE_NAMES[mode],
            "flight_mode": FLIGHT_MODES[mode],
            "failsafe": failsafe if mode == LAND else "",
        }
        if not r.has_pose:
            return VehicleState(**common)
        lat, lon = self.frame.to_wgs84(r.x, r.y)
        vn, ve, vd = self.frame.velocity_ned(r.vx, r.vy, r.vz)
        return VehicleState(
            lat=lat, lon=lon, alt=r.z, heading=self.frame.heading(r.yaw), vn=vn, ve=ve, vd=vd, **common
        )


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
