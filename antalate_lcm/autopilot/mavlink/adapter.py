"""`MavlinkAutopilot`: ArduCopter over MAVLink -- SITL or a real flight controller (docs/design.md §7, ``mavlink``).

The adapter is a small ground station: it speaks pymavlink over serial, UDP or TCP, keeps its own
picture of the vehicle from the telemetry the autopilot streams, and turns the HLC's few verbs into
ArduCopter's dialect (GUIDED mode, arming, MAV_CMD_NAV_TAKEOFF, velocity targets, LAND and RTL modes).

ArduCopter facts it is built around
-----------------------------------
* **A mode set while the autopilot is still booting is acknowledged, then silently reverted** when
  initialisation ends. So `arm` first waits for HEARTBEAT ``system_status`` STANDBY, and every mode
  change is confirmed by a HEARTBEAT received *after* the COMMAND_ACK showing the new ``custom_mode``.
* **Arming can succeed before the EKF uses GPS**; GUIDED then misbehaves. `arm` waits (up to
  ``ready_timeout``) for EKF_STATUS_REPORT with an absolute horizontal position (and not in constant
  position mode) and a GPS_RAW_INT 3D fix before it touches the mode or the motors.
* **MAV_CMD_NAV_TAKEOFF is refused outside GUIDED**, and an armed copter that does not take off disarms
  itself after ~10 s (DISARM_DELAY): the HLC takes off right after a successful arm, so that is enough.
* **Velocity targets expire after GUID_TIMEOUT (3 s)** in GUIDED. A background thread resends the current
  set-point ``velocity_resend_hz`` times a second while the copter flies in GUIDED -- but **never one
  older than ``setpoint_timeout``** (counted from the HLC's `set_velocity` call) and **never while the
  link is stale** (no message from the vehicle for ``link_stale_after``): a TCP link or a buffering radio
  keeps what is written during a cut and delivers it all when the link returns, and a field trial flew
  6.1 m on such a backlog while the HLC said LLC_DOWN. When messages flow again after a stale spell,
  a zero set-point goes out at once, so it reaches the vehicle right behind any backlog and stops it.
* A zero set-point while EXTENDED_SYS_STATE says TAKEOFF is not sent: the HLC's "hover once
  airborne" would otherwise cut the takeoff climb short a little below its target.
* **A mode change is a pilot's or a failsafe's**: ArduCopter's fence, battery, EKF and GCS failsafes
  switch modes exactly like a pilot's switch. `failsafe.FailsafeTracker` attributes a mode change the
  adapter did not command to the failsafe ArduPilot reported around it (SYS_STATUS health, FENCE_STATUS,
  BATTERY_STATUS, STATUSTEXT): `AutopilotState.failsafe` names it and RTL/LAND/BRAKE stay computer
  control (BRAKE = `FlightMode.HOLD`). Without such evidence LAND and the RTL family are still computer
  control; every other mode is a pilot's (``FlightMode.MANUAL``) and the HLC leaves the vehicle alone.
* **Link loss is HEARTBEAT silence**: `AutopilotState.link_age` is the age of the autopilot's last
  HEARTBEAT on the adapter's clock; the HLC compares it with ``link_timeout``.
* Every COMMAND_LONG is matched to its COMMAND_ACK by command id (only one command is in flight at a
  time); a command without ACK is sent once more (``confirmation`` 1) before `AutopilotError`.

Vehicle pre-flight checks
-------------------------
On connect the adapter reads the vehicle's own failsafe parameters (`vehicle_checks`: FS_GCS_ENABLE,
SYSID_MYGCS, GUID_TIMEOUT, FENCE_*, BATT_*) with PARAM_REQUEST_READ. Each one that leaves the vehicle
unprotected is written (PARAM_SET, confirmed by PARAM_VALUE) when ``configure_vehicle`` is set, and
otherwise logged as a warning with the exact value to set; with ``require_vehicle_failsafes`` `arm`
returns False and `last_refusal` names the parameter (the HLC puts it into its ``hlc_error_t``).

Identity and signing
--------------------
The adapter sends a GCS HEARTBEAT (``heartbeat_hz``) as system ``source_system`` (default **245**),
component ``source_component`` (default 191, MAV_COMP_ID_ONBOARD_COMPUTER). 245 rather than the
ground-station-typical 255 so that the adapter and a ground station (Mission Planner, QGroundControl,
MAVProxy: all 255) can share a link without mixing up their acknowledgements. ArduCopter's GCS failsafe
only watches heartbeats from ``SYSID_MYGCS`` (default 255): the pre-flight check says so.
With ``signing_key`` every message is MAVLink 2 signed and unsigned or badly signed messages from the
link are dropped and counted (`signing_rejected`).

The vehicle is found by its first HEARTBEAT from an autopilot component (MAV_COMP_ID_AUTOPILOT1, not a
GCS or a gimbal) unless ``target_system``/``target_component`` pin it; messages from anyone else are
ignored.

Threads
-------
``connect()`` starts a receive thread (decodes everything, keeps one snapshot under a lock, wakes the
command waiters) and a transmit thread (our HEARTBEAT and the velocity resend). Commands are blocking
(`blocking` = True: the HLC runs them on its worker thread); `set_velocity` and `state` never wait.
A TCP or serial link that drops is reopened by the receive thread every second until `close`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from pydantic import BaseModel
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm._ratelimit import RateLimitedLog
from antalate_lcm.autopilot.base import Autopilot, AutopilotError, AutopilotState, Clock, Frame
from antalate_lcm.autopilot.mavlink import failsafe as fs
from antalate_lcm.autopilot.mavlink import vehicle_checks
from antalate_lcm.autopilot.mavlink.failsafe import FLIGHT_MODES, FailsafeTracker
from antalate_lcm.autopilot.mavlink.params import DEFAULTS, Params, parse_params
from antalate_lcm.autopilot.mavlink.signing import allow_unsigned, signing_key, verify_signature_first
from antalate_lcm.autopilot.mavlink.vehicle_checks import Finding
from antalate_lcm.geo import wrap_360

log = logging.getLogger("antalate.autopilot.mavlink")

__all__ = ["DEFAULTS", "FLIGHT_MODES", "MavlinkAutopilot", "Params", "VELOCITY_TYPE_MASK", "mode_name"]

#: ArduCopter mode numbers (HEARTBEAT custom_mode) by name, from pymavlink's table.
COPTER_MODES: dict[str, int] = {name: number for number, name in mavutil.mode_mapping_acm.items()}
_MODE_NAMES: dict[int, str] = dict(mavutil.mode_mapping_acm)

# Velocity + yaw rate: ignore position, acceleration and yaw (bits set = ignored).
VELOCITY_TYPE_MASK = (
    mav.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_Z_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
)
_FRAMES = {Frame.NED: mav.MAV_FRAME_LOCAL_NED, Frame.BODY: mav.MAV_FRAME_BODY_OFFSET_NED}

# EKF_STATUS_REPORT: what "the EKF uses GPS" means here.
EKF_NEEDED = mav.EKF_ATTITUDE | mav.EKF_VELOCITY_HORIZ | mav.EKF_POS_HORIZ_ABS
EKF_FORBIDDEN = mav.EKF_CONST_POS_MODE | mav.EKF_UNINITIALIZED

_IN_AIR = frozenset({mav.MAV_LANDED_STATE_IN_AIR, mav.MAV_LANDED_STATE_TAKEOFF, mav.MAV_LANDED_STATE_LANDING})
_FLYING_STATUS = frozenset({mav.MAV_STATE_ACTIVE, mav.MAV_STATE_CRITICAL, mav.MAV_STATE_EMERGENCY})
_NOT_AUTOPILOT_TYPES = frozenset(
    {
        mav.MAV_TYPE_GCS,
        mav.MAV_TYPE_ONBOARD_CONTROLLER,
        mav.MAV_TYPE_GIMBAL,
        mav.MAV_TYPE_ADSB,
        mav.MAV_TYPE_CAMERA,
        mav.MAV_TYPE_ANTENNA_TRACKER,
    }
)

#: SYS_STATUS sensors whose health bit dropping is a failsafe (ArduPilot clears GEOFENCE on a breach,
#: BATTERY on a battery failsafe, AHRS when the EKF is unhealthy).
_HEALTH_FAILSAFES = (
    (mav.MAV_SYS_STATUS_GEOFENCE, fs.FENCE),
    (mav.MAV_SYS_STATUS_SENSOR_BATTERY, fs.BATTERY),
    (mav.MAV_SYS_STATUS_AHRS, fs.EKF),
)
#: BATTERY_STATUS charge_state -> `AutopilotState.battery_warning`.
_CHARGE_WARNINGS = {
    mav.MAV_BATTERY_CHARGE_STATE_LOW: "low",
    mav.MAV_BATTERY_CHARGE_STATE_CRITICAL: "critical",
    mav.MAV_BATTERY_CHARGE_STATE_EMERGENCY: "emergency",
    mav.MAV_BATTERY_CHARGE_STATE_FAILED: "failed",
}
_WARNING_RANK = {"": 0, "low": 1, "failsafe": 1, "critical": 2, "emergency": 3, "failed": 4}

#: Telemetry asked for with MAV_CMD_SET_MESSAGE_INTERVAL: (message, rate as a factor of stream_rate_hz).
STREAMS: tuple[tuple[str, float], ...] = (
    ("GLOBAL_POSITION_INT", 1.0),
    ("ATTITUDE", 1.0),
    ("VFR_HUD", 1.0),
    ("SYS_STATUS", 1.0),
    ("EXTENDED_SYS_STATE", 1.0),
    ("EKF_STATUS_REPORT", 1.0),
    ("GPS_RAW_INT", 1.0),
    ("HOME_POSITION", 0.1),
    ("BATTERY_STATUS", 0.4),
    ("FENCE_STATUS", 0.4),
)
#: The REQUEST_DATA_STREAM groups that carry the same messages (the fallback for old firmware).
DATA_STREAMS = (
    mav.MAV_DATA_STREAM_EXTENDED_STATUS,
    mav.MAV_DATA_STREAM_POSITION,
    mav.MAV_DATA_STREAM_EXTRA1,
    mav.MAV_DATA_STREAM_EXTRA2,
    mav.MAV_DATA_STREAM_EXTRA3,
)

_ZERO_RESEND = 1.0  # s a zero (hover) set-point is still resent, against a lost datagram
_REOPEN_DELAY = 1.0  # s between attempts to reopen a dropped TCP/serial link
_RX_POLL = 0.1  # s the receive thread blocks at most, so close() is prompt
_SETTLE = 3.0  # s connect() waits at most for the first position and landed-state reports
_REBOOT_GAP = 2.0  # s of HEARTBEAT silence after which the autopilot may have rebooted: ask for streams again
_PER_CELL_MAX_MV = 5000  # BATTERY_STATUS voltages[] below this are single cells (a per-cell monitor)


def _result_name(result: int | None) -> str:
    if result is None:
        return "no COMMAND_ACK"
    entry = mav.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else f"result {result}"


def _cmd_name(command: int) -> str:
    entry = mav.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"command {command}"


def _status_name(status: int | None) -> str:
    if status is None:
        return "unknown"
    entry = mav.enums["MAV_STATE"].get(status)
    return entry.name.removeprefix("MAV_STATE_") if entry is not None else str(status)


def mode_name(custom_mode: int) -> str:
    """ArduCopter's name for a HEARTBEAT ``custom_mode`` (``MODE_<n>`` for one pymavlink does not know)."""
    return _MODE_NAMES.get(custom_mode, f"MODE_{custom_mode}")


class _PeerClosed(ConnectionError):
    """The TCP peer closed the stream (pymavlink would otherwise just keep returning nothing)."""


@dataclass
class _Setpoint:
    """The last velocity target, kept for the resend thread."""

    frame: int
    vx: float
    vy: float
    vz: float
    yaw_rate: float  # deg/s, clockwise, like every yaw rate in antalate; rad/s only on the wire
    set_at: float  # clock time of the set_velocity() call: the set-point's age counts from here
    next_send: float

    @property
    def zero(self) -> bool:
        return self.vx == 0.0 and self.vy == 0.0 and self.vz == 0.0 and self.yaw_rate == 0.0


@dataclass
class _Vehicle:
    """What the autopilot last told us; guarded by `MavlinkAutopilot._cond`."""

    messages: int = 0  # count of messages accepted from the vehicle: marks "after" for waits
    rx_at: float | None = None  # clock time of the last message accepted from the vehicle (link staleness)
    heartbeats: int = 0
    heartbeat_at: float | None = None  # clock time of the last HEARTBEAT
    heartbeat_msg: int = 0  # `messages` count at the last HEARTBEAT: "a HEARTBEAT after the ACK"
    base_mode: int = 0
    custom_mode: int | None = None
    system_status: int | None = None
    lat: float = math.nan
    lon: float = math.nan
    alt: float = 0.0
    heading: float | None = None  # deg, from GLOBAL_POSITION_INT
    yaw: float | None = None  # deg, from ATTITUDE (fallback heading)
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0
    position_seen: bool = False
    battery: float = -1.0
    voltage: float = math.nan  # V, SYS_STATUS voltage_battery or the BATTERY_STATUS sum
    cells_seen: int = 0  # cells counted in BATTERY_STATUS (a per-cell monitor), 0 = not seen
    charge_warning: str = ""  # BATTERY_STATUS charge_state now: "low", "critical", "emergency", "failed"
    battery_warning: str = ""  # from STATUSTEXT / SYS_STATUS health: the worst since the last landing
    health: int | None = None  # SYS_STATUS onboard_control_sensors_health
    fence_breached: bool = False
    failsafes: FailsafeTracker = field(default_factory=FailsafeTracker)
    params: dict[str, float] = field(default_factory=dict)  # PARAM_VALUE by name
    param_types: dict[str, int] = field(default_factory=dict)
    param_at: dict[str, int] = field(default_factory=dict)  # name -> `messages` count when it arrived
    landed_state: int | None = None
    ekf_flags: int | None = None
    gps_fix: int | None = None
    home: tuple[float, float, float] | None = None  # lat, lon (deg), alt AMSL (m)
    acks: dict[int, tuple[int, int]] = field(default_factory=dict)  # command -> (result, at message #)
    texts: deque[tuple[int, int, str]] = field(
        default_factory=lambda: deque(maxlen=50)
    )  # (#, severity, text)

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str:
        return "" if self.custom_mode is None else mode_name(self.custom_mode)

    @property
    def in_air(self) -> bool:
        if self.landed_state is not None and self.landed_state != mav.MAV_LANDED_STATE_UNDEFINED:
            return self.landed_state in _IN_AIR
        # No EXTENDED_SYS_STATE: ArduCopter is ACTIVE while armed, so an armed vehicle counts as flying.
        return self.armed and self.system_status in _FLYING_STATUS

    @property
    def ekf_ok(self) -> bool:
        flags = self.ekf_flags
        return flags is not None and flags & EKF_NEEDED == EKF_NEEDED and not flags & EKF_FORBIDDEN

    def not_ready(self) -> list[str]:
        """Why the vehicle cannot be armed for GUIDED flight yet (empty: it can)."""
        reasons = []
        if self.system_status != mav.MAV_STATE_STANDBY and not self.armed:
            booting = self.system_status in (
                mav.MAV_STATE_BOOT,
                mav.MAV_STATE_CALIBRATING,
                mav.MAV_STATE_UNINIT,
            )
            reasons.append(
                f"system_status {_status_name(self.system_status)}"
                + (" (still booting)" if booting else " (not STANDBY)")
            )
        if not self.ekf_ok:
            flags = "no EKF_STATUS_REPORT" if self.ekf_flags is None else f"EKF flags 0x{self.ekf_flags:04x}"
            reasons.append(f"EKF has no absolute horizontal position ({flags})")
        if self.gps_fix is None or self.gps_fix < mav.GPS_FIX_TYPE_3D_FIX:
            reasons.append(
                "no GPS_RAW_INT" if self.gps_fix is None else f"GPS fix_type {self.gps_fix} (needs 3D)"
            )
        return reasons


class MavlinkAutopilot(Autopilot):
    """ArduCopter through pymavlink; see the module docstring for what it waits for and why."""

    name = "mavlink"
    blocking = True
    params_model: ClassVar[type[BaseModel]] = Params

    def __init__(self, params: Mapping[str, Any] | None = None, *, clock: Clock = time.monotonic) -> None:
        super().__init__(params, clock=clock)
        p = parse_params(self.params)
        self._p = p
        self.connection: str = p.connection
        self.source_system = p.source_system
        self._ack_timeout = p.ack_timeout
        self._mode_timeout = p.mode_timeout
        self._resend_period = 1.0 / p.velocity_resend_hz if p.velocity_resend_hz > 0 else 0.0
        self._setpoint_timeout = p.setpoint_timeout
        self._stale_after = p.link_stale_after
        self._heartbeat_period = 1.0 / p.heartbeat_hz
        self._key: bytes | None = signing_key(p.signing_key) if p.signing_key.strip() else None

        self._conn: Any = None  # the pymavlink connection (mavutil.mavfile)
        self._cond = threading.Condition()  # guards _v, _setpoint, _target; notified on every message
        self._send_lock = threading.Lock()  # one writer at a time on the link
        self._cmd_lock = threading.Lock()  # one command (and its ACK wait) at a time
        self._v = _Vehicle()
        self._setpoint: _Setpoint | None = None
        self._target: tuple[int, int] | None = None  # (system, component) of the autopilot
        self._commanded: tuple[str, float] | None = None  # (mode, clock time) of our last mode command
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._connected = False
        self._closed = False
        self._warned_autopilot = False
        self._rate_log = RateLimitedLog(log, period=10.0, clock=clock)
        #: The last arming refusal's reason (STATUSTEXT, or the failed pre-flight check), for the HLC.
        self.last_refusal = ""
        #: What the last vehicle pre-flight check found (empty: the vehicle's failsafes protect it).
        self.vehicle_findings: list[Finding] = []
        #: Messages dropped for a missing or wrong MAVLink 2 signature (with ``signing_key``).
        self.signing_rejected = 0
        #: Set-points not sent because they were too old or the link was stale.
        self.setpoints_withheld = 0
        self._vehicle_ok = False  # the last pre-flight check found nothing

    # ----------------------------------------------------------------- Autopilot contract

    def connect(self) -> None:
        """Open the link, find the autopilot by its HEARTBEAT, ask for telemetry.

        Bounded by ``connect_timeout``; on failure everything is released again, so the HLC's retry
        starts from scratch.
        """
        if self._connected:
            return
        self._closed = False
        self._stop = threading.Event()
        timeout = self._p.connect_timeout
        deadline = self.clock() + timeout
        try:
            self._conn = self._open_until(deadline)
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
            v = self._v
            target = self._target
            summary = f"mode {v.mode}, {_status_name(v.system_status)}, {'armed' if v.armed else 'disarmed'}"
            self._connected = True
        log.info(
            "connected to autopilot %s over %s: %s%s",
            target,
            self.connection,
            summary,
            ", MAVLink 2 signed" if self._key else "",
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

    def arm(self) -> bool:
        """Wait until the copter can fly GUIDED, switch to GUIDED, arm; False if the autopilot refused."""
        with self._cmd_lock:
            self._require_link("arm")
            with self._cond:
                ready = self._v.armed and self._v.mode == "GUIDED"
            if ready:
                return True
            if self._p.require_vehicle_failsafes:
                findings = [] if self._vehicle_ok else self._check_vehicle()
                if findings:
                    self.last_refusal = "vehicle pre-flight check: " + "; ".join(f.text() for f in findings)
                    log.warning("arming refused: %s", self.last_refusal)
                    return False
            self._wait_ready()
            self._set_mode("GUIDED")
            with self._cond:
                mark = self._v.messages
            result = self._command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            if result != mav.MAV_RESULT_ACCEPTED:
                reason = self._texts_since(mark) or self._latest_prearm()
                self.last_refusal = reason
                log.warning("arming refused (%s)%s", _result_name(result), f": {reason}" if reason else "")
                return False
            if not self._wait(lambda v: v.armed, self._mode_timeout):  # disarmed before: a fresh HEARTBEAT
                raise AutopilotError(
                    f"arming acknowledged but no HEARTBEAT showed the motors armed "
                    f"within {self._mode_timeout:g} s"
                )
            with self._cond:
                mode = self._v.mode
            if mode != "GUIDED":
                raise AutopilotError(f"armed, but the mode is {mode}, not GUIDED (changed behind our back)")
            log.info("armed in GUIDED")
            return True

    def disarm(self) -> None:
        with self._cmd_lock:
            self._require_link("disarm")
            with self._cond:
                mark = self._v.messages
            result = self._command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
            if result != mav.MAV_RESULT_ACCEPTED:
                raise AutopilotError(f"disarm refused ({_result_name(result)}){self._because(mark)}")

    def takeoff(self, alt: float) -> None:
        if not (math.isfinite(alt) and alt > 0.0):
            raise AutopilotError(f"takeoff refused: altitude {alt!r} must be > 0")
        with self._cmd_lock:
            self._require_link("takeoff")
            self._clear_setpoint()
            with self._cond:
                mark, mode, armed = self._v.messages, self._v.mode, self._v.armed
            result = self._command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, float(alt))
            if result != mav.MAV_RESULT_ACCEPTED:
                state = f"mode {mode}, {'armed' if armed else 'disarmed'}"
                raise AutopilotError(
                    f"takeoff to {alt:g} m refused ({_result_name(result)}; {state}){self._because(mark)}"
                )
            log.info("taking off to %g m", alt)

    def land(self) -> None:
        with self._cmd_lock:
            self._require_link("land")
            self._clear_setpoint()
            self._set_mode("LAND")

    def rtl(self) -> None:
        with self._cmd_lock:
            self._require_link("rtl")
            self._clear_setpoint()
            self._set_mode("RTL")

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        """Send a velocity target now and keep resending it (never blocks: no ACK exists for it)."""
        values = (vx, vy, vz, yaw_rate)
        if not all(math.isfinite(v) for v in values):
            raise AutopilotError(f"velocity refused: non-finite value in {values}")
        self._require_link("set_velocity")
        now = self.clock()
        sp = _Setpoint(
            _FRAMES[Frame(frame)],
            float(vx),
            float(vy),
            float(vz),
            float(yaw_rate),
            now,
            now + self._resend_period,
        )
        with self._cond:
            v = self._v
            if not (v.armed and v.mode == "GUIDED"):
                self._setpoint = None  # ArduCopter ignores targets outside GUIDED: nothing to keep alive
                return
            if self._stale(now):
                self._setpoint = None  # it would wait in a socket buffer and fly when the link returns
                self.setpoints_withheld += 1
                self._rate_log.log(
                    ("stale",),
                    logging.WARNING,
                    "velocity set-point withheld: nothing heard from the vehicle for %.1f s",
                    now - (v.rx_at or now),
                )
                return
            if sp.zero and v.landed_state == mav.MAV_LANDED_STATE_TAKEOFF:
                self._setpoint = None  # let the takeoff finish; it ends in a hover anyway
                return
            self._setpoint = sp if self._resend_period > 0 else None
        self._send_setpoint(sp)

    def state(self) -> AutopilotState:
        with self._cond:
            v = self._v
            if not self._connected:
                return AutopilotState(connected=False, link_age=math.inf)
            link_age = math.inf if v.heartbeat_at is None else max(0.0, self.clock() - v.heartbeat_at)
            mode = v.mode
            flight_mode, autonomous, failsafe = fs.classify(mode, v.failsafes.reason)
            heading = v.heading if v.heading is not None else (v.yaw if v.yaw is not None else 0.0)
            return AutopilotState(
                connected=True,
                link_age=link_age,
                lat=v.lat,
                lon=v.lon,
                alt=v.alt,
                heading=heading,
                vn=v.vn,
                ve=v.ve,
                vd=v.vd,
                battery=v.battery,
                armed=v.armed,
                in_air=v.in_air,
                autonomous=autonomous,
                mode=mode,
                flight_mode=flight_mode,
                failsafe=failsafe,
                voltage=v.voltage,
                cells=self._p.cells or v.cells_seen,
                battery_warning=max(
                    v.charge_warning, v.battery_warning, key=lambda w: _WARNING_RANK.get(w, 1)
                ),
            )

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

    # ----------------------------------------------------------------- link

    def _open(self) -> Any:
        p = self._p
        if self._key is not None and "MAVLINK20" not in os.environ:
            # Signing needs MAVLink 2 from the first byte: pymavlink's switch on the first v2 frame it
            # hears replaces its codec and would drop the signing state. (pymavlink sets the same
            # process-wide switch itself as soon as it hears MAVLink 2.)
            os.environ["MAVLINK20"] = "1"
            mavutil.set_dialect("ardupilotmega")
        try:
            conn = mavutil.mavlink_connection(
                self.connection,
                baud=p.baud,
                source_system=self.source_system,
                source_component=p.source_component,
                autoreconnect=False,
                retries=0,
            )
        except (OSError, ValueError) as exc:
            raise AutopilotError(f"cannot open {self.connection}: {exc}") from exc
        if self._key is not None:
            if conn.WIRE_PROTOCOL_VERSION != "2.0":
                conn.close()
                raise AutopilotError(
                    "MAVLink 2 signing needs MAVLink 2, but pymavlink opened a MAVLink 1 codec"
                )
            conn.setup_signing(self._key, sign_outgoing=True, allow_unsigned_callback=allow_unsigned)
            verify_signature_first(conn.mav)
        if self.connection.startswith(("tcp:", "uds:", "unix:")):
            # pymavlink only prints on EOF and keeps returning nothing: make it an error we handle.
            def closed_by_peer() -> None:
                raise _PeerClosed(f"{self.connection} closed by the peer")

            conn.handle_eof = closed_by_peer
            conn.handle_disconnect = closed_by_peer
        return conn

    def _open_until(self, deadline: float) -> Any:
        """Open the link, retrying a refused TCP connection (SITL still starting) until `deadline`."""
        while True:
            try:
                return self._open()
            except AutopilotError as exc:
                if isinstance(exc.__cause__, ValueError):
                    raise  # a malformed connection string: retrying cannot help
                if self.clock() >= deadline or self._stop.wait(0.5):
                    raise AutopilotError(
                        f"{exc} (is SITL/the autopilot running, and is this the right port?)"
                    ) from exc.__cause__

    def _start_threads(self) -> None:
        self._threads = [
            threading.Thread(target=self._receive_loop, name=f"mavlink-rx {self.connection}", daemon=True),
            threading.Thread(target=self._transmit_loop, name=f"mavlink-tx {self.connection}", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _shutdown(self) -> None:
        self._stop.set()
        with self._cond:
            self._setpoint = None
            self._cond.notify_all()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        with self._send_lock:
            conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.close()

    def _require_link(self, what: str) -> None:
        if self._closed or self._conn is None:
            raise AutopilotError(f"{what}: not connected")

    def _send(self, fn: Callable[[Any], None]) -> None:
        """Write one message (``fn(conn.mav)``); raises `AutopilotError` if the link cannot take it."""
        with self._send_lock:
            conn = self._conn
            if conn is None:
                raise AutopilotError("not connected")
            try:
                fn(
                    conn.mav
                )  # conn.mav is replaced when pymavlink switches to MAVLink 2: look it up each time
            except OSError as exc:
                raise AutopilotError(f"cannot send on {self.connection}: {exc}") from exc

    # ----------------------------------------------------------------- receiving

    def _receive_loop(self) -> None:
        stop = self._stop
        while not stop.is_set():
            conn = self._conn
            if conn is None:
                return
            try:
                msg = conn.recv_match(blocking=True, timeout=_RX_POLL)
            except (OSError, ValueError) as exc:  # ValueError: select() on a socket closed by close()
                if stop.is_set():
                    return
                self._link_dropped(exc)
                continue
            if msg is not None:
                try:
                    self._on_message(msg)
                except Exception as exc:  # noqa: BLE001 - one odd message must not end reception
                    self._rate_log.log(
                        ("decode", msg.get_type()),
                        logging.WARNING,
                        "cannot use %s from the autopilot: %r",
                        msg.get_type(),
                        exc,
                    )

    def _link_dropped(self, exc: BaseException) -> None:
        """A stream link (TCP, serial) failed: reopen it until it comes back or we are closed."""
        self._rate_log.log(
            ("dropped",),
            logging.WARNING,
            "link %s failed (%s): reopening every %g s",
            self.connection,
            exc,
            _REOPEN_DELAY,
        )
        while not self._stop.wait(_REOPEN_DELAY):
            try:
                new = self._open()
            except AutopilotError as err:
                self._rate_log.log(("reopen",), logging.INFO, "%s", err)
                continue
            with self._send_lock:
                old, self._conn = self._conn, new
            if old is not None:
                with contextlib.suppress(OSError):
                    old.close()
            if self._stop.is_set():
                new.close()
                return
            log.info("link %s reopened", self.connection)
            self._rerequest_streams()  # a reopened stream link usually means a rebooted autopilot
            return

    def _is_our_autopilot(self, msg: Any) -> bool:
        want_sys = self._p.target_system
        want_comp = self._p.target_component or mav.MAV_COMP_ID_AUTOPILOT1
        return (
            msg.autopilot != mav.MAV_AUTOPILOT_INVALID
            and msg.type not in _NOT_AUTOPILOT_TYPES
            and msg.get_srcComponent() == want_comp
            and want_sys in (0, msg.get_srcSystem())
        )

    def _on_message(self, msg: Any) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            if "signature" in str(getattr(msg, "reason", "")):
                self.signing_rejected += 1
                self._rate_log.log(
                    ("signature",),
                    logging.WARNING,
                    "message with a missing or wrong MAVLink 2 signature dropped (%d so far)",
                    self.signing_rejected,
                )
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        stop: _Setpoint | None = None
        with self._cond:
            if self._target is None:
                if mtype != "HEARTBEAT" or not self._is_our_autopilot(msg):
                    return
                self._target = source
                self._check_autopilot_kind(msg)
            if source != self._target:
                return
            v = self._v
            now = self.clock()
            if self._stale(now) and v.armed and v.mode == "GUIDED" and v.in_air:
                # Back after a stale spell: whatever we wrote before noticing may be flushed to the vehicle
                # right now. A stop sent at once arrives right behind it.
                stop = _Setpoint(_FRAMES[Frame.NED], 0.0, 0.0, 0.0, 0.0, now, now + self._resend_period)
                self._setpoint = None
            v.rx_at = now
            v.messages += 1
            handler = _HANDLERS.get(mtype)
            if handler is not None:
                handler(self, v, msg)
            self._cond.notify_all()
        if stop is not None:
            log.warning(
                "link back after a stale spell: stopping the vehicle (zero velocity) until the HLC commands"
            )
            try:
                self._send_setpoint(stop)
            except AutopilotError as exc:
                self._rate_log.log(("resend",), logging.WARNING, "stop not sent: %s", exc)

    def _stale(self, now: float) -> bool:
        """Nothing heard from the vehicle for ``link_stale_after`` (lock held)."""
        rx_at = self._v.rx_at
        return rx_at is None or now - rx_at > self._stale_after

    def _check_autopilot_kind(self, msg: Any) -> None:
        if self._warned_autopilot:
            return
        self._warned_autopilot = True
        if msg.autopilot != mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
            log.warning(
                "autopilot %s is not ArduPilot (MAV_AUTOPILOT %d): this adapter speaks ArduCopter's modes",
                self._target,
                msg.autopilot,
            )

    def _on_heartbeat(self, v: _Vehicle, msg: Any) -> None:
        previous = v.custom_mode
        now = self.clock()
        if v.heartbeat_at is not None and now - v.heartbeat_at > _REBOOT_GAP:
            log.info("HEARTBEAT back after %.1f s: asking for telemetry again", now - v.heartbeat_at)
            self._rerequest_streams()
        v.heartbeats += 1
        v.heartbeat_at = now
        v.heartbeat_msg = v.messages
        was_armed = v.armed
        v.base_mode = msg.base_mode
        v.custom_mode = msg.custom_mode
        v.system_status = msg.system_status
        commanded = (
            self._commanded is not None
            and self._commanded[0] == v.mode
            and now - self._commanded[1] <= 2 * self._ack_timeout + self._mode_timeout + 1.0
        )
        v.failsafes.on_mode(v.mode, now, commanded=commanded)
        if previous != msg.custom_mode and v.failsafes.reason:
            log.warning("autopilot failsafe (%s): mode %s", v.failsafes.reason, v.mode)
        if was_armed and not v.armed:
            v.battery_warning = ""  # landed and disarmed: what is still wrong, BATTERY_STATUS keeps saying
        if previous != msg.custom_mode:
            if previous is not None:
                log.info("autopilot mode %s -> %s", mode_name(previous), mode_name(msg.custom_mode))
            if mode_name(msg.custom_mode) != "GUIDED":
                self._setpoint = None  # out of GUIDED (a pilot, a failsafe): never resume an old target
        if not v.armed:
            self._setpoint = None

    def _on_global_position(self, v: _Vehicle, msg: Any) -> None:
        known = msg.lat != 0 or msg.lon != 0  # ArduCopter sends 0, 0 until it has a position
        v.lat = msg.lat / 1e7 if known else math.nan
        v.lon = msg.lon / 1e7 if known else math.nan
        v.alt = msg.relative_alt / 1000.0
        v.vn, v.ve, v.vd = msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0
        v.heading = None if msg.hdg == 65535 else wrap_360(msg.hdg / 100.0)
        v.position_seen = True

    def _on_attitude(self, v: _Vehicle, msg: Any) -> None:
        v.yaw = wrap_360(math.degrees(msg.yaw))

    def _on_sys_status(self, v: _Vehicle, msg: Any) -> None:
        v.battery = float(msg.battery_remaining) if 0 <= msg.battery_remaining <= 100 else -1.0
        if 0 < msg.voltage_battery < 0xFFFF:
            v.voltage = msg.voltage_battery / 1000.0
        now = self.clock()
        v.health = msg.onboard_control_sensors_health
        for bit, reason in _HEALTH_FAILSAFES:
            enabled = msg.onboard_control_sensors_enabled & bit and msg.onboard_control_sensors_present & bit
            unhealthy = bool(enabled) and not msg.onboard_control_sensors_health & bit
            v.failsafes.set_active(reason, unhealthy, now)
            if reason == fs.BATTERY and unhealthy:
                self._battery_warning(v, "failsafe")

    def _on_battery_status(self, v: _Vehicle, msg: Any) -> None:
        if msg.id != 0:
            return  # the first battery is the one SYS_STATUS describes
        cells = [mv for mv in msg.voltages if mv != 0xFFFF]
        cells += [mv for mv in getattr(msg, "voltages_ext", []) or [] if mv not in (0, 0xFFFF)]
        if cells:
            v.voltage = sum(cells) / 1000.0
            if len(cells) >= 2 and all(0 < mv < _PER_CELL_MAX_MV for mv in cells):
                v.cells_seen = len(cells)  # a per-cell monitor (SMBus, DroneCAN); ArduPilot's analog splits
        if 0 <= msg.battery_remaining <= 100:
            v.battery = float(msg.battery_remaining)
        warning = _CHARGE_WARNINGS.get(getattr(msg, "charge_state", 0), "")
        v.failsafes.set_active(fs.BATTERY, bool(warning), self.clock())
        if warning != v.charge_warning:
            log.warning("autopilot battery charge state: %s (%.2f V)", warning or "ok", v.voltage)
        v.charge_warning = warning

    def _battery_warning(self, v: _Vehicle, warning: str) -> None:
        if _WARNING_RANK.get(warning, 1) > _WARNING_RANK.get(v.battery_warning, 1) or not v.battery_warning:
            if v.battery_warning != warning:
                log.warning("autopilot battery warning: %s (%.2f V)", warning, v.voltage)
            v.battery_warning = warning

    def _on_fence_status(self, v: _Vehicle, msg: Any) -> None:
        breached = bool(msg.breach_status)
        if breached and not v.fence_breached:
            log.warning(
                "autopilot reports a fence breach (type %d, %d so far)", msg.breach_type, msg.breach_count
            )
        v.fence_breached = breached
        v.failsafes.set_active(fs.FENCE, breached, self.clock())

    def _on_param_value(self, v: _Vehicle, msg: Any) -> None:
        name = (
            msg.param_id if isinstance(msg.param_id, str) else bytes(msg.param_id).decode("ascii", "replace")
        )
        name = name.rstrip("\x00")
        v.params[name] = float(msg.param_value)
        v.param_types[name] = int(msg.param_type)
        v.param_at[name] = v.messages

    def _on_extended_sys_state(self, v: _Vehicle, msg: Any) -> None:
        v.landed_state = msg.landed_state

    def _on_ekf(self, v: _Vehicle, msg: Any) -> None:
        v.ekf_flags = msg.flags

    def _on_gps(self, v: _Vehicle, msg: Any) -> None:
        v.gps_fix = msg.fix_type

    def _on_home(self, v: _Vehicle, msg: Any) -> None:
        v.home = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)

    def _on_ack(self, v: _Vehicle, msg: Any) -> None:
        target = getattr(msg, "target_system", 0)  # a MAVLink 2 extension: 0 when absent
        if target not in (0, self.source_system):
            return  # another ground station's acknowledgement
        v.acks[msg.command] = (msg.result, v.messages)

    def _on_statustext(self, v: _Vehicle, msg: Any) -> None:
        text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("utf-8", "replace")
        text = text.rstrip("\x00").strip()
        v.texts.append((v.messages, msg.severity, text))
        v.failsafes.event(fs.text_failsafe(text), self.clock())
        level = fs.text_battery_level(text)
        if level:
            self._battery_warning(v, level)
        level = logging.WARNING if msg.severity <= mav.MAV_SEVERITY_WARNING else logging.INFO
        log.log(level, "autopilot says: %s", text)

    # ----------------------------------------------------------------- transmitting

    def _transmit_loop(self) -> None:
        next_heartbeat = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            if now >= next_heartbeat:
                next_heartbeat = max(next_heartbeat + self._heartbeat_period, now)
                try:
                    self._send(
                        lambda m: m.heartbeat_send(
                            mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
                        )
                    )
                except AutopilotError as exc:
                    self._rate_log.log(("heartbeat",), logging.WARNING, "HEARTBEAT not sent: %s", exc)
            due = self._due_setpoint(now)
            if due is not None:
                try:
                    self._send_setpoint(due)
                except AutopilotError as exc:
                    self._rate_log.log(("resend",), logging.WARNING, "velocity resend failed: %s", exc)
            with self._cond:
                sp = self._setpoint
                wake = next_heartbeat if sp is None else min(next_heartbeat, sp.next_send)
            self._stop.wait(min(max(wake - self.clock(), 0.005), 0.1))

    def _due_setpoint(self, now: float) -> _Setpoint | None:
        """The set-point to resend now, if any; drops one that has expired or no longer applies."""
        with self._cond:
            sp = self._setpoint
            if sp is None or now < sp.next_send:
                return None
            v = self._v
            hold = min(_ZERO_RESEND, self._setpoint_timeout) if sp.zero else self._setpoint_timeout
            expired = now - sp.set_at >= hold
            if expired or not (v.armed and v.mode == "GUIDED" and v.in_air):
                self._setpoint = None
                return None
            if self._stale(now):
                self._setpoint = None  # never queue a set-point into a cut link (see the module docstring)
                self.setpoints_withheld += 1
                return None
            sp.next_send = max(sp.next_send + self._resend_period, now)
            return sp

    def _send_setpoint(self, sp: _Setpoint) -> None:
        ts, tc = self._target or (1, 1)
        boot_ms = int(self.clock() * 1000) & 0xFFFFFFFF
        self._send(
            lambda m: m.set_position_target_local_ned_send(
                boot_ms,
                ts,
                tc,
                sp.frame,
                VELOCITY_TYPE_MASK,
                0,
                0,
                0,
                sp.vx,
                sp.vy,
                sp.vz,
                0,
                0,
                0,
                0,
                math.radians(sp.yaw_rate),
            )
        )

    def _clear_setpoint(self) -> None:
        with self._cond:
            self._setpoint = None

    # ----------------------------------------------------------------- commands

    def _wait(self, predicate: Callable[[_Vehicle], bool], timeout: float) -> bool:
        """Block until ``predicate(snapshot)`` holds (True) or `timeout` s pass (False); raises if closed."""
        deadline = self.clock() + timeout
        with self._cond:
            while True:
                if self._stop.is_set():
                    raise AutopilotError("closed while waiting for the autopilot")
                if predicate(self._v):
                    return True
                left = deadline - self.clock()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.1))

    def _command_result(self, command: int, *params: float, attempts: int = 2) -> int | None:
        """Send COMMAND_LONG `command`, return its COMMAND_ACK's MAV_RESULT (None: never acknowledged)."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        for confirmation in range(attempts):
            with self._cond:
                mark = self._v.messages
                ts, tc = self._target or (1, 1)
            self._send(lambda m, c=confirmation, ts=ts, tc=tc: m.command_long_send(ts, tc, command, c, *p))

            def acked(v: _Vehicle, mark: int = mark) -> bool:
                ack = v.acks.get(command)
                return ack is not None and ack[1] > mark and ack[0] != mav.MAV_RESULT_IN_PROGRESS

            if self._wait(acked, self._ack_timeout):
                with self._cond:
                    return self._v.acks[command][0]
            log.debug(
                "%s: no COMMAND_ACK after %g s (attempt %d)",
                _cmd_name(command),
                self._ack_timeout,
                confirmation + 1,
            )
        return None

    def _command(self, command: int, *params: float) -> int:
        result = self._command_result(command, *params)
        if result is None:
            raise AutopilotError(
                f"{_cmd_name(command)}: no COMMAND_ACK from {self.connection} "
                f"(2 attempts, {self._ack_timeout:g} s each)"
            )
        return result

    def _set_mode(self, name: str) -> None:
        """Switch to ArduCopter mode `name` and confirm it by a HEARTBEAT received after the ACK."""
        number = COPTER_MODES[name]
        with self._cond:
            mark = self._v.messages
            self._commanded = (name, self.clock())
        result = self._command_result(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)
        if result == mav.MAV_RESULT_UNSUPPORTED:
            result = self._set_mode_message(number)  # the SET_MODE message: older firmware
        if result is None:
            raise AutopilotError(
                f"mode {name}: no COMMAND_ACK from {self.connection} "
                f"(2 attempts, {self._ack_timeout:g} s each)"
            )
        if result != mav.MAV_RESULT_ACCEPTED:
            raise AutopilotError(f"mode {name} refused ({_result_name(result)}){self._because(mark)}")
        with self._cond:
            acks = self._v.acks
            ack_at = max(
                at
                for cmd, (_, at) in acks.items()
                if cmd in (mav.MAV_CMD_DO_SET_MODE, mav.MAVLINK_MSG_ID_SET_MODE) and at > mark
            )
        if not self._wait(lambda v: v.heartbeat_msg > ack_at and v.custom_mode == number, self._mode_timeout):
            with self._cond:
                shown = self._v.mode
            raise AutopilotError(
                f"mode {name} acknowledged but HEARTBEAT still shows {shown} after {self._mode_timeout:g} s"
            )
        log.info("mode %s confirmed", name)

    def _set_mode_message(self, number: int) -> int | None:
        with self._cond:
            mark = self._v.messages
            ts = (self._target or (1, 1))[0]
        self._send(lambda m: m.set_mode_send(ts, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number))

        def acked(v: _Vehicle) -> bool:
            ack = v.acks.get(mav.MAVLINK_MSG_ID_SET_MODE)
            return ack is not None and ack[1] > mark

        if self._wait(acked, self._ack_timeout):
            with self._cond:
                return self._v.acks[mav.MAVLINK_MSG_ID_SET_MODE][0]
        return None

    def _wait_ready(self) -> None:
        timeout = self._p.ready_timeout
        with self._cond:
            reasons = self._v.not_ready()
        if reasons:
            log.info("waiting up to %g s before arming: %s", timeout, "; ".join(reasons))
        if not self._wait(lambda v: not v.not_ready(), timeout):
            with self._cond:
                reasons = self._v.not_ready()
            raise AutopilotError(f"not ready to arm after {timeout:g} s: {'; '.join(reasons)}")

    def _rerequest_streams(self) -> None:
        """Ask for the streams again, off the receive thread (the requests wait for ACKs it delivers)."""
        if not self._connected:
            return  # connect() is asking anyway

        def run() -> None:
            try:
                self._request_streams()
            except AutopilotError as exc:
                self._rate_log.log(("streams",), logging.WARNING, "telemetry request failed: %s", exc)

        threading.Thread(target=run, name=f"mavlink-streams {self.connection}", daemon=True).start()

    def _request_streams(self) -> None:
        """Ask for the telemetry `state` needs: SET_MESSAGE_INTERVAL, or REQUEST_DATA_STREAM if unsupported."""
        rate = self._p.stream_rate_hz
        for i, (name, factor) in enumerate(STREAMS):
            msg_id = getattr(mav, f"MAVLINK_MSG_ID_{name}")
            result = self._command_result(
                mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / (rate * factor), attempts=1
            )
            if i == 0 and result in (None, mav.MAV_RESULT_UNSUPPORTED, mav.MAV_RESULT_DENIED):
                log.info(
                    "SET_MESSAGE_INTERVAL %s (%s): falling back to REQUEST_DATA_STREAM",
                    _result_name(result).lower(),
                    name,
                )
                self._request_data_streams(max(1, round(rate)))
                return
            if result != mav.MAV_RESULT_ACCEPTED:
                log.debug("SET_MESSAGE_INTERVAL %s: %s", name, _result_name(result))

    def _request_data_streams(self, hz: int) -> None:
        ts, tc = self._target or (1, 1)
        for stream in DATA_STREAMS:
            self._send(lambda m, s=stream: m.request_data_stream_send(ts, tc, s, hz, 1))

    # ----------------------------------------------------------------- vehicle parameters

    def read_params(
        self, names: tuple[str, ...] | list[str], groups: tuple[tuple[str, ...], ...] | None = None
    ) -> dict[str, float]:
        """The named parameters the vehicle reports (PARAM_REQUEST_READ, two rounds); absent ones are left out.

        All requests go out at once and the answers are collected together, so a slow radio costs two
        ``ack_timeout`` at most, not one per parameter. The read is complete when one name of each of
        `groups` arrived (default: every name); a firmware without a parameter never answers for it.
        """
        groups = tuple((n,) for n in names) if groups is None else groups
        with self._cond:
            mark = self._v.messages

        def complete(v: _Vehicle) -> bool:
            return all(any(v.param_at.get(n, -1) > mark for n in group) for group in groups)

        wanted = list(names)
        for _ in range(2):
            ts, tc = self._target or (1, 1)
            for name in wanted:
                self._send(
                    lambda m, n=name, ts=ts, tc=tc: m.param_request_read_send(ts, tc, n.encode("ascii"), -1)
                )
            self._wait(complete, self._ack_timeout)
            with self._cond:
                if complete(self._v):
                    break
                wanted = [n for n in names if self._v.param_at.get(n, -1) <= mark]
        with self._cond:
            return {n: self._v.params[n] for n in names if self._v.param_at.get(n, -1) > mark}

    def set_param(self, name: str, value: float) -> None:
        """PARAM_SET `name` and wait for the PARAM_VALUE that confirms it; `AutopilotError` otherwise."""
        with self._cond:
            ptype = self._v.param_types.get(name, mav.MAV_PARAM_TYPE_REAL32)
        for _ in range(2):
            with self._cond:
                mark = self._v.messages
                ts, tc = self._target or (1, 1)
            self._send(
                lambda m, ts=ts, tc=tc: m.param_set_send(ts, tc, name.encode("ascii"), float(value), ptype)
            )

            def confirmed(v: _Vehicle, mark: int = mark) -> bool:
                return v.param_at.get(name, -1) > mark and abs(v.params[name] - value) <= 1e-3 * max(
                    1.0, abs(value)
                )

            if self._wait(confirmed, self._ack_timeout):
                log.warning("vehicle parameter %s set to %g (configure_vehicle)", name, value)
                return
        with self._cond:
            shown = self._v.params.get(name)
        raise AutopilotError(
            f"PARAM_SET {name} = {value:g} not confirmed by the vehicle (it reports {shown})"
        )

    def _check_vehicle(self) -> list[Finding]:
        """The pre-flight check of the vehicle's own failsafes (module docstring); the findings left."""
        p = self._p
        values = self.read_params(vehicle_checks.READ, vehicle_checks.REQUIRED_GROUPS)
        findings = vehicle_checks.check(
            values, source_system=self.source_system, max_guid_timeout=p.max_guid_timeout, cells=p.cells
        )
        if p.configure_vehicle and any(f.settable for f in findings):
            for f in findings:
                if f.settable and f.want is not None:
                    try:
                        self.set_param(f.param, f.want)
                    except AutopilotError as exc:
                        log.warning("%s", exc)
            values = self.read_params(vehicle_checks.READ, vehicle_checks.REQUIRED_GROUPS)
            findings = vehicle_checks.check(
                values, source_system=self.source_system, max_guid_timeout=p.max_guid_timeout, cells=p.cells
            )
        for f in findings:
            log.warning("vehicle pre-flight check: %s", f.text())
        if not findings:
            log.info(
                "vehicle pre-flight check: failsafe parameters OK (%s)",
                ", ".join(f"{k}={v:g}" for k, v in sorted(values.items())),
            )
        self.vehicle_findings = findings
        self._vehicle_ok = not findings
        return findings

    # ----------------------------------------------------------------- STATUSTEXT reasons

    def _texts_since(self, mark: int) -> str:
        with self._cond:
            texts = [t for n, sev, t in self._v.texts if n > mark and sev <= mav.MAV_SEVERITY_WARNING]
        return "; ".join(texts)

    def _latest_prearm(self) -> str:
        with self._cond:
            return next((t for _, _, t in reversed(self._v.texts) if t.startswith(("PreArm", "Arm"))), "")

    def _because(self, mark: int) -> str:
        reason = self._texts_since(mark)
        return f": {reason}" if reason else ""


_HANDLERS: dict[str, Callable[[MavlinkAutopilot, _Vehicle, Any], None]] = {
    "HEARTBEAT": MavlinkAutopilot._on_heartbeat,
    "GLOBAL_POSITION_INT": MavlinkAutopilot._on_global_position,
    "ATTITUDE": MavlinkAutopilot._on_attitude,
    "SYS_STATUS": MavlinkAutopilot._on_sys_status,
    "EXTENDED_SYS_STATE": MavlinkAutopilot._on_extended_sys_state,
    "EKF_STATUS_REPORT": MavlinkAutopilot._on_ekf,
    "GPS_RAW_INT": MavlinkAutopilot._on_gps,
    "HOME_POSITION": MavlinkAutopilot._on_home,
    "COMMAND_ACK": MavlinkAutopilot._on_ack,
    "BATTERY_STATUS": MavlinkAutopilot._on_battery_status,
    "FENCE_STATUS": MavlinkAutopilot._on_fence_status,
    "PARAM_VALUE": MavlinkAutopilot._on_param_value,
    "STATUSTEXT": MavlinkAutopilot._on_statustext,
}
