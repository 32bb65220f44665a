"""`MavlinkAdapter`: ArduCopter over MAVLink -- SITL or a real flight controller (docs/design.md §7, ``mavlink``).

The adapter is a small ground station: it speaks pymavlink over serial, UDP or TCP, keeps its own
picture of the vehicle from the telemetry the autopilot streams, and turns the HLC's few verbs into
ArduCopter's dialect (GUIDED mode, arming, MAV_CMD_NAV_TAKEOFF, velocity targets, LAND and RTL modes).
This module is those verbs; `connection` is the link, its threads and the velocity resend (and who the
adapter is on the link: identity, signing), `commands` the COMMAND_ACK and mode-change waits, the
parameter reads and the vehicle's pre-flight check.

ArduCopter facts it is built around
-----------------------------------
* **A mode set while the autopilot is still booting is acknowledged, then silently reverted** when
  initialisation ends. So `arm` first waits for HEARTBEAT ``system_status`` STANDBY, and every mode
  change is confirmed by a HEARTBEAT received *after* the COMMAND_ACK (`commands`).
* **Arming can succeed before the EKF uses GPS**; GUIDED then misbehaves. `arm` waits (up to
  ``ready_timeout``) for EKF_STATUS_REPORT with an absolute horizontal position (and not in constant
  position mode) and a GPS_RAW_INT 3D fix before it touches the mode or the motors.
* **MAV_CMD_NAV_TAKEOFF is refused outside GUIDED**, and an armed copter that does not take off disarms
  itself after ~10 s (DISARM_DELAY): the HLC takes off right after a successful arm, so that is enough.
* **Velocity targets expire after GUID_TIMEOUT (3 s)** in GUIDED: the transmit thread resends them, never
  an old one and never into a stale link (`connection`, `setpoints`).
* A zero set-point while EXTENDED_SYS_STATE says TAKEOFF is not sent: the HLC's "hover once
  airborne" would otherwise cut the takeoff climb short a little below its target.
* **A mode change is a pilot's or a failsafe's**: ArduCopter's fence, battery, EKF and GCS failsafes
  switch modes exactly like a pilot's switch. `failsafe.FailsafeTracker` attributes a mode change the
  adapter did not command to the failsafe ArduPilot reported around it (SYS_STATUS health, FENCE_STATUS,
  BATTERY_STATUS, STATUSTEXT): `VehicleState.failsafe` names it and RTL/LAND/BRAKE stay computer
  control (BRAKE = `FlightMode.HOLD`). Without such evidence LAND and the RTL family are still computer
  control; every other mode is a pilot's (``FlightMode.MANUAL``) and the HLC leaves the vehicle alone.
* **Link loss is HEARTBEAT silence**: `VehicleState.link_age` is the age of the autopilot's last
  HEARTBEAT on the adapter's clock; the HLC compares it with ``link_timeout``.

Commands are blocking (`blocking` = True: the HLC runs them on its worker thread); `set_velocity` and
`state` never wait.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, ClassVar

from pydantic import BaseModel
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.base import (
    AutopilotError,
    Frame,
    VehicleState,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.vehicles.kit import Workers
from antalate_lcm.vehicles.mavlink.commands import MavlinkCommands
from antalate_lcm.vehicles.mavlink.dialect import COPTER_MODES, VELOCITY_TYPE_MASK, mode_name, result_name
from antalate_lcm.vehicles.mavlink.failsafe import FLIGHT_MODES
from antalate_lcm.vehicles.mavlink.link import MavLink
from antalate_lcm.vehicles.mavlink.params import DEFAULTS, Params
from antalate_lcm.vehicles.mavlink.setpoints import Verdict

log = logging.getLogger("antalate.autopilot.mavlink")

__all__ = [
    "COPTER_MODES",
    "DEFAULTS",
    "FLIGHT_MODES",
    "LinkOpener",
    "MavlinkAdapter",
    "Params",
    "VELOCITY_TYPE_MASK",
    "mode_name",
]

#: Opens the link for the validated parameters; called on `connect` and on every reopen.
LinkOpener = Callable[[Params], MavLink]

_SETTLE = 3.0  # s connect() waits at most for the first position and landed-state reports


class MavlinkAdapter(MavlinkCommands):
    """ArduCopter through pymavlink; see the module docstring for what it waits for and why.

    ``link`` opens the link instead of pymavlink's connection (a `link.MemoryLink` in tests).
    """

    name = "mavlink"
    blocking = True
    params_model: ClassVar[type[BaseModel]] = Params

    def _setup(self) -> None:
        super()._setup()
        #: The last arming refusal's reason (STATUSTEXT, or the failed pre-flight check), for the HLC.
        self.last_refusal = ""

    # ----------------------------------------------------------------- Vehicle adapter contract

    def connect(self) -> None:
        """Open the link, find the autopilot by its HEARTBEAT, ask for telemetry.

        Bounded by ``connect_timeout``; on failure everything is released again, so the HLC's retry
        starts from scratch.
        """
        if self._connected:
            return
        self._closed = False
        self._workers = Workers()  # a fresh stop event: a thread of the last connection stays stopped
        timeout = self._p.connect_timeout
        deadline = self.clock() + timeout
        try:
            self._link = self._open_until(deadline)
            self._start_threads()
            if not self._wait(lambda v: v.heartbeats > 0, deadline - self.clock()):
                rejected = (
                    (
                        f"; {self.signing_rejected} message(s) dropped for a missing or wrong MAVLink 2 "
                        "signature: does the vehicle have the same signing key?"
                    )
                    if self.signing_rejected
                    else ""
                )
                raise AutopilotError(
                    f"no HEARTBEAT from {self.connection} within {timeout:g} s: "
                    f"is SITL/the autopilot running, and is this the right port?{rejected}"
                )
            self._request_streams()
            self._wait(lambda v: v.position_seen and v.landed_state is not None, _SETTLE)
        except BaseException:
            self._shutdown()
            raise
        with self._cond:
            target = self._target
            summary = self._v.summary()
            self._connected = True
        log.info(
            "connected to autopilot %s over %s: %s%s",
            target,
            self.connection,
            summary,
            ", MAVLink 2 signed" if self._signed else "",
        )
        if self._p.check_vehicle:
            try:
                with self._cmd_lock:
                    self._check_vehicle()
            except AutopilotError as exc:  # the check must never cost the connection
                log.warning("vehicle pre-flight check failed: %s", exc)

    def close(self) -> None:
        self._closed = True
        self._connected = False
        self._shutdown()

    #: The mode the adapter arms in (and flies its commands from).
    _arm_mode: ClassVar[str] = "GUIDED"

    def arm(self) -> bool:
        """Wait until the vehicle can fly, switch to `_arm_mode`, arm; False if the autopilot refused."""
        with self._cmd_lock:
            self._require_link("arm")
            with self._cond:
                ready = self._v.armed and self._armed_ours()
            if ready:
                return True
            if self._p.require_vehicle_failsafes:
                findings = [] if self._vehicle_ok else self._check_vehicle()
                if findings:
                    self.last_refusal = "vehicle pre-flight check: " + "; ".join(f.text() for f in findings)
                    log.warning("arming refused: %s", self.last_refusal)
                    return False
            self._wait_ready()
            self._enter_arm_mode()
            with self._cond:
                mark = self._v.messages
            result = self._command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            if result != mav.MAV_RESULT_ACCEPTED:
                with self._cond:
                    reason = self._v.texts_since(mark) or self._v.latest_prearm()
                self.last_refusal = reason
                log.warning("arming refused (%s)%s", result_name(result), f": {reason}" if reason else "")
                return False
            if not self._wait(lambda v: v.armed, self._mode_timeout):  # disarmed before: a fresh HEARTBEAT
                raise AutopilotError(
                    f"arming acknowledged but no HEARTBEAT showed the motors armed "
                    f"within {self._mode_timeout:g} s"
                )
            with self._cond:
                mode = self._v.mode
                self._armed_in(mode)
            if mode != self._arm_mode:
                raise AutopilotError(
                    f"armed, but the mode is {mode}, not {self._arm_mode} (changed behind our back)"
                )
            log.info("armed in %s", self._arm_mode)
            return True

    def _armed_ours(self) -> bool:
        """Whether an armed vehicle is already ours to command (lock held): arming again is then a no-op."""
        return self._v.mode == self._arm_mode

    def _enter_arm_mode(self) -> None:
        self._set_mode(self._arm_mode)

    def _armed_in(self, mode: str) -> None:
        """The vehicle armed showing `mode` (lock held)."""

    def disarm(self) -> None:
        with self._cmd_lock:
            self._require_link("disarm")
            with self._cond:
                mark = self._v.messages
            result = self._command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
            if result != mav.MAV_RESULT_ACCEPTED:
                raise AutopilotError(f"disarm refused ({result_name(result)}){self._because(mark)}")

    def takeoff(self, alt: float) -> None:
        """MAV_CMD_NAV_TAKEOFF to `alt` m (`_takeoff_target`); `AutopilotError` saying why if refused."""
        check_takeoff_altitude(alt)
        with self._cmd_lock:
            self._require_link("takeoff")
            self._clear_setpoint()
            with self._cond:
                mark, mode, armed = self._v.messages, self._v.mode, self._v.armed
                params, where = self._takeoff_target(alt)
            result = self._command(mav.MAV_CMD_NAV_TAKEOFF, *params)
            if result != mav.MAV_RESULT_ACCEPTED:
                state = f"mode {mode}, {'armed' if armed else 'disarmed'}"
                raise AutopilotError(
                    f"takeoff to {alt:g} m refused ({result_name(result)}; {state}){self._because(mark)}"
                )
            log.info("taking off to %s", where)

    def _takeoff_target(self, alt: float) -> tuple[tuple[float, ...], str]:
        """MAV_CMD_NAV_TAKEOFF's seven parameters for `alt` m, and that target as the log says it (lock held).

        ArduCopter takes param7 as the height above home.
        """
        return (0, 0, 0, 0, 0, 0, float(alt)), f"{alt:g} m"

    #: The flight stack's modes for `land` and `rtl`.
    _land_mode: ClassVar[str] = "LAND"
    _rtl_mode: ClassVar[str] = "RTL"

    def land(self) -> None:
        self._mode_command("land", self._land_mode)

    def rtl(self) -> None:
        self._mode_command("rtl", self._rtl_mode)

    def _mode_command(self, what: str, mode: str) -> None:
        """A command that is a mode change (the set-point stream stops)."""
        with self._cmd_lock:
            self._require_link(what)
            self._clear_setpoint()
            self._set_mode(mode)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        """Send a velocity target now and keep resending it (never blocks: no ACK exists for it)."""
        check_velocity(vx, vy, vz, yaw_rate)
        self._require_link("set_velocity")
        now = self.clock()
        sp = self._rules.new(Frame(frame), float(vx), float(vy), float(vz), float(yaw_rate), now)
        with self._cond:
            verdict = self._rules.judge(self._v, sp, now)
            self._setpoint = self._rules.keep(sp) if verdict is Verdict.SEND else None
            if verdict is Verdict.WITHHOLD:
                self.setpoints_withheld += 1
                self._rate_log.log(
                    ("stale",),
                    logging.WARNING,
                    "velocity set-point withheld: nothing heard from the vehicle for %.1f s",
                    now - (self._v.rx_at or now),
                )
        if verdict is Verdict.SEND:
            self._send_setpoint(sp)

    def state(self) -> VehicleState:
        with self._cond:
            if not self._connected:
                return VehicleState(connected=False, link_age=math.inf)
            return self._v.vehicle_state(self.clock(), self._p.cells)

    # ----------------------------------------------------------------- extras (tools, tests)

    @property
    def target(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot talked to, once its HEARTBEAT was heard."""
        with self._cond:
            return self._target

    @property
    def home(self) -> tuple[float, float, float] | None:
        """Home (lat, lon in deg, altitude AMSL in m) from HOME_POSITION, if the autopilot sent it."""
        with self._cond:
            return self._v.home

    @property
    def resending(self) -> bool:
        """Whether a velocity set-point is currently being kept alive."""
        with self._cond:
            return self._setpoint is not None

    def ready_reasons(self) -> list[str]:
        """Why `arm` would still wait (empty when the vehicle is ready for GUIDED flight)."""
        with self._cond:
            return self._v.not_ready()


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
