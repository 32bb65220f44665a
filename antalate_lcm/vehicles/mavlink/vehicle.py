"""The adapter's picture of the vehicle, built from the telemetry ArduCopter streams (pure, no I/O).

`Vehicle.update` takes one decoded message from the autopilot and the time it arrived; it returns what
the adapter must do about it (`Update`: drop the velocity set-point, ask for telemetry again). Nothing
here sends, waits or reads a clock, so every rule is tested with hand-made messages.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.base.deprecation import renamed_attribute
from antalate_lcm.base.geo import wrap_360
from antalate_lcm.vehicles.base import VehicleState
from antalate_lcm.vehicles.mavlink import failsafe as fs
from antalate_lcm.vehicles.mavlink.dialect import (
    EKF_FORBIDDEN,
    EKF_NEEDED,
    FLYING_STATUS,
    IN_AIR,
    mode_name,
    status_name,
    text,
)
from antalate_lcm.vehicles.mavlink.failsafe import FailsafeTracker

log = logging.getLogger("antalate.autopilot.mavlink")

#: SYS_STATUS sensors whose health bit dropping is a failsafe (ArduPilot clears GEOFENCE on a breach,
#: BATTERY on a battery failsafe, AHRS when the EKF is unhealthy, RC_RECEIVER while the radio is lost --
#: ArduCopter 4.6.3 SITL with SIM_RC_FAIL 1 clears it with "Radio Failsafe" and sets it again with
#: "Radio Failsafe Cleared"; the bit is present only once RC input has ever been seen).
HEALTH_FAILSAFES = (
    (mav.MAV_SYS_STATUS_GEOFENCE, fs.FENCE),
    (mav.MAV_SYS_STATUS_SENSOR_BATTERY, fs.BATTERY),
    (mav.MAV_SYS_STATUS_AHRS, fs.EKF),
    (mav.MAV_SYS_STATUS_SENSOR_RC_RECEIVER, fs.RC),
)
#: BATTERY_STATUS charge_state -> `VehicleState.battery_warning`.
CHARGE_WARNINGS = {
    mav.MAV_BATTERY_CHARGE_STATE_LOW: "low",
    mav.MAV_BATTERY_CHARGE_STATE_CRITICAL: "critical",
    mav.MAV_BATTERY_CHARGE_STATE_EMERGENCY: "emergency",
    mav.MAV_BATTERY_CHARGE_STATE_FAILED: "failed",
}
WARNING_RANK = {"": 0, "low": 1, "failsafe": 1, "critical": 2, "emergency": 3, "failed": 4}
REBOOT_GAP = 2.0  # s of HEARTBEAT silence after which the autopilot may have rebooted: ask for streams again
PER_CELL_MAX_MV = 5000  # BATTERY_STATUS voltages[] below this are single cells (a per-cell monitor)


@dataclass(frozen=True)
class Update:
    """What a message asks of the adapter."""

    drop_setpoint: bool = False  # out of GUIDED or disarmed: never resume an old velocity target
    request_streams: bool = False  # HEARTBEAT back after a silence: the autopilot may have rebooted


_NOTHING = Update()


@dataclass
class Vehicle:
    """What the autopilot last told us.

    ``source_system`` is our own system id (acknowledgements for other ground stations are ignored);
    ``commanded`` is the mode we last commanded and when, and ``command_window`` how long a HEARTBEAT
    showing that mode counts as ours rather than a pilot's or a failsafe's.
    """

    source_system: int = 245
    command_window: float = 5.0
    commanded: tuple[str, float] | None = None

    messages: int = 0  # count of messages accepted from the vehicle: marks "after" for waits
    rx_at: float | None = None  # time of the last message accepted from the vehicle (link staleness)
    heartbeats: int = 0
    heartbeat_at: float | None = None  # time of the last HEARTBEAT
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
    battery_warning: str = ""  # from STATUSTEXT: the worst since the last landing or healthy report
    health_failsafe: bool = False  # SYS_STATUS: the monitor reads and its health bit is cleared (a level)
    battery_unknown: bool = False  # SYS_STATUS: a monitor is enabled but has not read yet (boot)
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

    # ------------------------------------------------------------------ derived

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str:
        return "" if self.custom_mode is None else mode_name(self.custom_mode)

    @property
    def in_air(self) -> bool:
        if self.landed_state is not None and self.landed_state != mav.MAV_LANDED_STATE_UNDEFINED:
            return self.landed_state in IN_AIR
        # No EXTENDED_SYS_STATE: ArduCopter is ACTIVE while armed, so an armed vehicle counts as flying.
        return self.armed and self.system_status in FLYING_STATUS

    #: The mode in which velocity targets fly the vehicle (ArduCopter's GUIDED; PX4's OFFBOARD).
    velocity_mode: ClassVar[str] = "GUIDED"

    @property
    def flying_guided(self) -> bool:
        """Armed, in `velocity_mode` and in the air: the only time a velocity target moves the vehicle."""
        return self.armed and self.mode == self.velocity_mode and self.in_air

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
                f"system_status {status_name(self.system_status)}"
                + (" (still booting)" if booting else " (not STANDBY)")
            )
        if not self.ekf_ok:
            flags = "no EKF_STATUS_REPORT" if self.ekf_flags is None else f"EKF flags 0x{self.ekf_flags:04x}"
            reasons.append(f"EKF has no absolute horizontal position ({flags})")
        if self.battery_unknown:
            reasons.append("battery unknown (the autopilot's battery monitor has not reported yet)")
        if self.gps_fix is None or self.gps_fix < mav.GPS_FIX_TYPE_3D_FIX:
            reasons.append(
                "no GPS_RAW_INT" if self.gps_fix is None else f"GPS fix_type {self.gps_fix} (needs 3D)"
            )
        return reasons

    def ack_after(self, command: int, mark: int, *, final: bool = True) -> int | None:
        """The MAV_RESULT of `command`'s COMMAND_ACK received after message `mark` (None: none yet).

        Only one command is in flight at a time, so the command id matches an ACK to its COMMAND_LONG.
        With `final`, an IN_PROGRESS acknowledgement does not count: the real answer follows.
        """
        ack = self.acks.get(command)
        if ack is None or ack[1] <= mark or (final and ack[0] == mav.MAV_RESULT_IN_PROGRESS):
            return None
        return ack[0]

    def param_after(self, name: str, mark: int) -> bool:
        """Whether a PARAM_VALUE for `name` arrived after message `mark`."""
        return self.param_at.get(name, -1) > mark

    def texts_since(self, mark: int) -> str:
        """The warnings (or worse) ArduPilot said after message `mark`, joined."""
        return "; ".join(t for n, sev, t in self.texts if n > mark and sev <= mav.MAV_SEVERITY_WARNING)

    def latest_prearm(self) -> str:
        return next((t for _, _, t in reversed(self.texts) if t.startswith(("PreArm", "Arm"))), "")

    def summary(self) -> str:
        return f"mode {self.mode}, {status_name(self.system_status)}, {'armed' if self.armed else 'disarmed'}"

    if not TYPE_CHECKING:  # the old name, one release (issue #26's vocabulary); mypy sees only the new
        autopilot_state = renamed_attribute("vehicle_state")

    def vehicle_state(self, now: float, cells: int = 0) -> VehicleState:
        """The HLC's view at `now` (``cells`` from the config, 0 = as counted from BATTERY_STATUS)."""
        link_age = math.inf if self.heartbeat_at is None else max(0.0, now - self.heartbeat_at)
        mode = self.mode
        flight_mode, autonomous, failsafe = fs.classify(mode, self.failsafes.reason)
        heading = self.heading if self.heading is not None else (self.yaw if self.yaw is not None else 0.0)
        return VehicleState(
            connected=True,
            link_age=link_age,
            lat=self.lat,
            lon=self.lon,
            alt=self.alt,
            heading=heading,
            vn=self.vn,
            ve=self.ve,
            vd=self.vd,
            battery=self.battery,
            armed=self.armed,
            in_air=self.in_air,
            autonomous=autonomous,
            mode=mode,
            flight_mode=flight_mode,
            failsafe=failsafe,
            voltage=self.voltage,
            cells=cells or self.cells_seen,
            battery_warning=max(
                self.charge_warning,
                self.battery_warning,
                "failsafe" if self.health_failsafe else "",
                key=lambda w: WARNING_RANK.get(w, 1),
            ),
        )

    # ------------------------------------------------------------------ updates

    def update(self, msg: Any, now: float) -> Update:
        """Take one message from the autopilot, received at `now`."""
        self.rx_at = now
        self.messages += 1
        handler = _HANDLERS.get(msg.get_type())
        return _NOTHING if handler is None else handler(self, msg, now) or _NOTHING

    def _take_heartbeat(self, msg: Any, now: float) -> bool:
        """Count the autopilot's HEARTBEAT and take its modes and status; True after a silence long
        enough to be a reboot (its telemetry must be asked for again)."""
        silence = 0.0 if self.heartbeat_at is None else now - self.heartbeat_at
        request = silence > REBOOT_GAP
        if request:
            log.info("HEARTBEAT back after %.1f s: asking for telemetry again", silence)
        self.heartbeats += 1
        self.heartbeat_at = now
        self.heartbeat_msg = self.messages
        self.base_mode = msg.base_mode
        self.custom_mode = msg.custom_mode
        self.system_status = msg.system_status
        return request

    def _on_heartbeat(self, msg: Any, now: float) -> Update:
        previous, was_armed = self.custom_mode, self.armed
        request = self._take_heartbeat(msg, now)
        commanded = (
            self.commanded is not None
            and self.commanded[0] == self.mode
            and now - self.commanded[1] <= self.command_window
        )
        if previous != msg.custom_mode and not commanded and self.commanded is not None:
            # The vehicle left for a mode we did not ask for (a failsafe, a pilot): our command is spent.
            # Kept, a failsafe's LAND seconds after the operator's LAND -> failsafe RTL would count as ours.
            self.commanded = None
        self.failsafes.on_mode(self.mode, now, commanded=commanded)
        if previous != msg.custom_mode and self.failsafes.reason:
            log.warning("autopilot failsafe (%s): mode %s", self.failsafes.reason, self.mode)
        if was_armed and not self.armed:
            self.battery_warning = ""  # landed and disarmed: what is still wrong, BATTERY_STATUS keeps saying
        drop = not self.armed
        if previous != msg.custom_mode:
            if previous is not None:
                log.info("autopilot mode %s -> %s", mode_name(previous), mode_name(msg.custom_mode))
            drop = drop or self.mode != "GUIDED"  # a pilot, a failsafe: never resume an old target
        return Update(drop_setpoint=drop, request_streams=request)

    def _on_global_position(self, msg: Any, now: float) -> None:
        known = msg.lat != 0 or msg.lon != 0  # ArduCopter sends 0, 0 until it has a position
        self.lat = msg.lat / 1e7 if known else math.nan
        self.lon = msg.lon / 1e7 if known else math.nan
        self.alt = msg.relative_alt / 1000.0
        self.vn, self.ve, self.vd = msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0
        self.heading = None if msg.hdg == 65535 else wrap_360(msg.hdg / 100.0)
        self.position_seen = True

    def _on_attitude(self, msg: Any, now: float) -> None:
        self.yaw = wrap_360(math.degrees(msg.yaw))

    def _on_sys_status(self, msg: Any, now: float) -> None:
        self.battery = float(msg.battery_remaining) if 0 <= msg.battery_remaining <= 100 else -1.0
        reading = 0 < msg.voltage_battery < 0xFFFF
        if reading:
            self.voltage = msg.voltage_battery / 1000.0
        for bit, reason in HEALTH_FAILSAFES:
            enabled = msg.onboard_control_sensors_enabled & bit and msg.onboard_control_sensors_present & bit
            unhealthy = bool(enabled) and not msg.onboard_control_sensors_health & bit
            if reason == fs.BATTERY:
                unhealthy = self._battery_health(bool(enabled), unhealthy, reading or self.battery >= 0)
            self.failsafes.set_active(reason, unhealthy, now)

    def _battery_health(self, enabled: bool, unhealthy: bool, reading: bool) -> bool:
        """Whether the SYS_STATUS battery bit says failsafe; sets `battery_unknown` and `health_failsafe`.

        ArduPilot clears the bit when the monitor is not healthy *or* has failsafed
        (GCS_Common.cpp, Copter-4.6.3: ``battery.healthy() && !battery.has_failsafed()``). A monitor that
        has not read yet -- the first SYS_STATUS after boot says 0 mV, -1 % (measured on ArduCopter 4.6.3
        SITL) -- is unhealthy, not low: that is "battery unknown", never a failsafe. The bit is a level
        the firmware keeps cleared while its failsafe lasts, so nothing here is latched.
        """
        self.battery_unknown = enabled and unhealthy and not reading
        failsafe = unhealthy and reading
        if failsafe and not self.health_failsafe:
            log.warning("autopilot battery failsafe (SYS_STATUS battery unhealthy, %.2f V)", self.voltage)
        self.health_failsafe = failsafe
        if enabled and not unhealthy and self.battery_warning:
            # The vehicle says its battery is healthy and not failsafed: a warning we kept from an
            # earlier report (a STATUSTEXT) no longer holds.
            log.info("autopilot battery healthy again: warning %r cleared", self.battery_warning)
            self.battery_warning = ""
        return failsafe

    def _on_battery_status(self, msg: Any, now: float) -> None:
        if msg.id != 0:
            return  # the first battery is the one SYS_STATUS describes
        cells = [mv for mv in msg.voltages if mv != 0xFFFF]
        cells += [mv for mv in getattr(msg, "voltages_ext", []) or [] if mv not in (0, 0xFFFF)]
        if cells:
            self.voltage = sum(cells) / 1000.0
            if len(cells) >= 2 and all(0 < mv < PER_CELL_MAX_MV for mv in cells):
                self.cells_seen = len(
                    cells
                )  # a per-cell monitor (SMBus, DroneCAN); ArduPilot's analog splits
        if 0 <= msg.battery_remaining <= 100:
            self.battery = float(msg.battery_remaining)
        warning = CHARGE_WARNINGS.get(getattr(msg, "charge_state", 0), "")
        self.failsafes.set_active(fs.BATTERY, bool(warning), now)
        if warning != self.charge_warning:
            log.warning("autopilot battery charge state: %s (%.2f V)", warning or "ok", self.voltage)
        self.charge_warning = warning

    def _battery_warning(self, warning: str) -> None:
        if (
            WARNING_RANK.get(warning, 1) > WARNING_RANK.get(self.battery_warning, 1)
            or not self.battery_warning
        ):
            if self.battery_warning != warning:
                log.warning("autopilot battery warning: %s (%.2f V)", warning, self.voltage)
            self.battery_warning = warning

    def _on_fence_status(self, msg: Any, now: float) -> None:
        breached = bool(msg.breach_status)
        if breached and not self.fence_breached:
            log.warning(
                "autopilot reports a fence breach (type %d, %d so far)", msg.breach_type, msg.breach_count
            )
        self.fence_breached = breached
        self.failsafes.set_active(fs.FENCE, breached, now)

    def _on_param_value(self, msg: Any, now: float) -> None:
        name = text(msg.param_id, "ascii")
        self.params[name] = float(msg.param_value)
        self.param_types[name] = int(msg.param_type)
        self.param_at[name] = self.messages

    def _on_extended_sys_state(self, msg: Any, now: float) -> None:
        self.landed_state = msg.landed_state

    def _on_ekf(self, msg: Any, now: float) -> None:
        self.ekf_flags = msg.flags

    def _on_gps(self, msg: Any, now: float) -> None:
        self.gps_fix = msg.fix_type

    def _on_home(self, msg: Any, now: float) -> None:
        self.home = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)

    def _on_ack(self, msg: Any, now: float) -> None:
        target = getattr(msg, "target_system", 0)  # a MAVLink 2 extension: 0 when absent
        if target not in (0, self.source_system):
            return  # another ground station's acknowledgement
        self.acks[msg.command] = (msg.result, self.messages)

    def _on_statustext(self, msg: Any, now: float) -> None:
        said = text(msg.text).strip()
        self.texts.append((self.messages, msg.severity, said))
        self.failsafes.event(fs.text_failsafe(said), now)
        level = fs.text_battery_level(said)
        if level:
            self._battery_warning(level)
        log.log(
            logging.WARNING if msg.severity <= mav.MAV_SEVERITY_WARNING else logging.INFO,
            "autopilot says: %s",
            said,
        )


_HANDLERS: dict[str, Callable[[Vehicle, Any, float], Update | None]] = {
    "HEARTBEAT": Vehicle._on_heartbeat,
    "GLOBAL_POSITION_INT": Vehicle._on_global_position,
    "ATTITUDE": Vehicle._on_attitude,
    "SYS_STATUS": Vehicle._on_sys_status,
    "EXTENDED_SYS_STATE": Vehicle._on_extended_sys_state,
    "EKF_STATUS_REPORT": Vehicle._on_ekf,
    "GPS_RAW_INT": Vehicle._on_gps,
    "HOME_POSITION": Vehicle._on_home,
    "COMMAND_ACK": Vehicle._on_ack,
    "BATTERY_STATUS": Vehicle._on_battery_status,
    "FENCE_STATUS": Vehicle._on_fence_status,
    "PARAM_VALUE": Vehicle._on_param_value,
    "STATUSTEXT": Vehicle._on_statustext,
}
