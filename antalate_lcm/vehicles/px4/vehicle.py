"""The adapter's picture of a PX4 vehicle: the shared `Vehicle` with PX4's modes, readiness and failsafes (pure).

Everything PX4 reports like ArduCopter (position, attitude, battery, landed state, GPS, acknowledgements,
STATUSTEXT, parameters) is taken by `antalate_lcm.vehicles.mavlink.vehicle.Vehicle`; this subclass adds
what differs (PX4 v1.15.4 sources cited where used):

* the mode name comes from PX4's ``custom_mode`` (`modes`);
* who owns the mode: the adapter's commands (`Px4Vehicle.ours`), PX4's failsafe (``system_status``
  CRITICAL, reason from `failsafe`), or anybody else -- a pilot or another ground station;
* readiness: SYS_STATUS's MAV_SYS_STATUS_PREARM_CHECK health bit (PX4's own arming checks,
  src/modules/mavlink/streams/SYS_STATUS.hpp), HOME_POSITION, ESTIMATOR_STATUS with an absolute
  horizontal position and a 3D GPS fix;
* integer parameters arrive byte-wise in PARAM_VALUE's float (PX4 advertises
  MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE; src/modules/mavlink/mavlink_parameters.cpp).
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass, replace
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import VehicleState
from antalate_lcm.vehicles.mavlink.dialect import status_name, text
from antalate_lcm.vehicles.mavlink.failsafe import FENCE, GCS
from antalate_lcm.vehicles.mavlink.vehicle import Update, Vehicle
from antalate_lcm.vehicles.px4 import failsafe as fs
from antalate_lcm.vehicles.px4 import modes

log = logging.getLogger("antalate.autopilot.px4")

#: ESTIMATOR_STATUS flags that mean "the estimator has an absolute position" (the EKF2 flags PX4 sends,
#: src/modules/mavlink/streams/ESTIMATOR_STATUS.hpp).
ESTIMATOR_NEEDED = mav.ESTIMATOR_ATTITUDE | mav.ESTIMATOR_VELOCITY_HORIZ | mav.ESTIMATOR_POS_HORIZ_ABS
ESTIMATOR_FORBIDDEN = mav.ESTIMATOR_CONST_POS_MODE
#: Integer parameter types PX4 packs byte-wise into the float.
INT_TYPES = frozenset(
    {
        mav.MAV_PARAM_TYPE_UINT8,
        mav.MAV_PARAM_TYPE_INT8,
        mav.MAV_PARAM_TYPE_UINT16,
        mav.MAV_PARAM_TYPE_INT16,
        mav.MAV_PARAM_TYPE_UINT32,
        mav.MAV_PARAM_TYPE_INT32,
    }
)


def decode_param(value: float, param_type: int) -> float:
    """A PARAM_VALUE's number: an integer type's bits are the integer (byte-wise encoding)."""
    if param_type in INT_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", value))[0])
    return float(value)


def encode_param(value: float, param_type: int) -> float:
    """The float to put in PARAM_SET for `value` of `param_type` (the inverse of `decode_param`)."""
    if param_type in INT_TYPES:
        return float(struct.unpack("<f", struct.pack("<i", round(value)))[0])
    return float(value)


@dataclass
class Px4Vehicle(Vehicle):
    """What PX4 last told us; `ours` says whether the current mode came from the adapter's commands.

    ``datalink_loss_after`` is COM_DL_LOSS_T as the adapter last read it: a failsafe after a stale spell
    at least that long is PX4's data-link-loss failsafe.
    """

    datalink_loss_after: float = 10.0
    ours: bool = False
    px4_failsafe: str = ""
    estimator_flags: int | None = None
    prearm_ok: bool = False
    battery_unhealthy: bool = False
    fence_unhealthy: bool = False
    fence_text_at: float = -math.inf
    link_text_at: float = -math.inf
    silence_before: float = 0.0  # s of silence before the last message (the longest recent gap)
    silence_at: float = -math.inf

    @property
    def mode(self) -> str:
        return "" if self.custom_mode is None else modes.mode_name(self.custom_mode)

    velocity_mode = "OFFBOARD"  # the only mode in which a velocity set-point moves the vehicle

    @property
    def ekf_ok(self) -> bool:
        flags = self.estimator_flags
        return (
            flags is not None
            and flags & ESTIMATOR_NEEDED == ESTIMATOR_NEEDED
            and not flags & ESTIMATOR_FORBIDDEN
        )

    @property
    def failsafe_flag(self) -> bool:
        """PX4's HEARTBEAT says a failsafe is active (armed + ``vehicle_status.failsafe``)."""
        return self.armed and self.system_status == mav.MAV_STATE_CRITICAL

    def not_ready(self) -> list[str]:
        """Why PX4 cannot be armed for an antalate flight yet (empty: it can)."""
        reasons = []
        if self.system_status != mav.MAV_STATE_STANDBY and not self.armed:
            reasons.append(f"system_status {status_name(self.system_status)} (not STANDBY)")
        if not self.prearm_ok:
            said = self.latest_prearm()
            reasons.append("PX4's pre-arm checks fail" + (f" ({said})" if said else ""))
        if self.home is None:
            reasons.append("no HOME_POSITION")
        if not self.ekf_ok:
            flags = (
                "no ESTIMATOR_STATUS"
                if self.estimator_flags is None
                else f"flags 0x{self.estimator_flags:04x}"
            )
            reasons.append(f"estimator has no absolute horizontal position ({flags})")
        if self.gps_fix is None or self.gps_fix < mav.GPS_FIX_TYPE_3D_FIX:
            reasons.append(
                "no GPS_RAW_INT" if self.gps_fix is None else f"GPS fix_type {self.gps_fix} (needs 3D)"
            )
        return reasons

    def latest_prearm(self) -> str:
        return next((t for _, _, t in reversed(self.texts) if t.startswith(("Preflight", "Arming"))), "")

    def vehicle_state(self, now: float, cells: int = 0) -> VehicleState:
        base = super().vehicle_state(now, cells)
        flight_mode, autonomous, failsafe = modes.classify(
            self.mode, ours=self.ours, failsafe=self.px4_failsafe
        )
        return replace(base, flight_mode=flight_mode, autonomous=autonomous, failsafe=failsafe)

    # ------------------------------------------------------------------ updates

    def update(self, msg: Any, now: float) -> Update:
        if self.rx_at is not None and now - self.rx_at > 0.5:
            self.silence_before, self.silence_at = now - self.rx_at, now
        mtype = msg.get_type()
        if mtype == "HEARTBEAT":
            self.rx_at = now
            self.messages += 1
            return self._on_px4_heartbeat(msg, now)
        update = super().update(msg, now)
        if mtype == "PARAM_VALUE":
            self.params[text(msg.param_id, "ascii")] = decode_param(msg.param_value, msg.param_type)
        elif mtype == "ESTIMATOR_STATUS":
            self.estimator_flags = msg.flags
        elif mtype == "SYS_STATUS":
            self._on_px4_sys_status(msg)
        elif mtype == "STATUSTEXT":
            evidence = fs.text_evidence(self.texts[-1][2]) if self.texts else ""
            if evidence == FENCE:
                self.fence_text_at = now
            elif evidence == GCS:
                self.link_text_at = now
        return update

    def _on_px4_sys_status(self, msg: Any) -> None:
        self.prearm_ok = bool(msg.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)

        def unhealthy(bit: int) -> bool:
            present = msg.onboard_control_sensors_present & msg.onboard_control_sensors_enabled & bit
            return bool(present) and not msg.onboard_control_sensors_health & bit

        self.battery_unhealthy = unhealthy(mav.MAV_SYS_STATUS_SENSOR_BATTERY)
        self.fence_unhealthy = unhealthy(mav.MAV_SYS_STATUS_GEOFENCE)

    def _px4_failsafe(self, previous_mode: str, now: float) -> str:
        recent = 5.0
        return fs.reason(
            left_offboard=previous_mode == "OFFBOARD",
            battery=bool(self.charge_warning) or self.battery_unhealthy,
            fence=self.fence_unhealthy or now - self.fence_text_at <= recent,
            link_lost=now - self.link_text_at <= recent
            or (self.silence_before >= self.datalink_loss_after and now - self.silence_at <= recent),
        )

    def _on_px4_heartbeat(self, msg: Any, now: float) -> Update:
        previous, previous_mode, was_armed = self.custom_mode, self.mode, self.armed
        request = self._take_heartbeat(msg, now)
        mode = self.mode
        changed = previous != msg.custom_mode
        carried = ""
        if changed:
            commanded = (
                self.commanded is not None
                and self.commanded[0] == mode
                and now - self.commanded[1] <= self.command_window
            )
            # PX4 ends our take-off in Hold by itself (commander: AUTO_TAKEOFF finished -> AUTO_LOITER).
            takeoff_done = self.ours and previous_mode == "AUTO.TAKEOFF" and mode == modes.HOLD
            # An adapter (re)started in flight finds PX4 in OFFBOARD or Hold without a failsafe: where our
            # take-off, hold and set-points leave it, so it resyncs as ours (`modes.RESYNC_MODES`).
            adopted = previous is None and self.armed and mode in modes.RESYNC_MODES
            self.ours = (commanded or takeoff_done or adopted) and not self.failsafe_flag
            # A failsafe's hold (COM_FAIL_ACT_T) followed by its action is one failsafe: keep its reason.
            carried, self.px4_failsafe = self.px4_failsafe, ""
            if previous is not None:
                log.info("autopilot mode %s -> %s", previous_mode, mode)
        if self.failsafe_flag and not self.px4_failsafe and not (self.ours and not changed):
            self.ours = False
            self.px4_failsafe = carried or self._px4_failsafe(previous_mode if changed else "", now)
            log.warning("autopilot failsafe (%s): mode %s", self.px4_failsafe, mode)
        if was_armed and not self.armed:
            self.battery_warning = ""
            self.ours = False
        drop = not self.armed or (changed and mode != "OFFBOARD" and not self.ours)
        return Update(drop_setpoint=drop, request_streams=request)
