"""What the adapter logs from a Crazyflie and what the values mean, apart from I/O.

Log variables are the firmware's own (stabilizer.c ``stateEstimate``, pm_stm32f4.c ``pm``,
estimator_kalman.c ``kalman``, supervisor.c ``supervisor.info``). A log packet carries at most 26
bytes of values, so the state is split in two blocks; each variable is fetched as its stored type.
The supervisor's ``info`` is a bitfield (cflib/crazyflie/supervisor.py lists the bits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

#: The log blocks: name -> variables, each within one log packet (26 bytes of values): the pose is 6
#: floats (24 bytes), the status 2 floats + int8 + uint8 + uint16 (12), the estimator 3 floats (12).
LOG_BLOCKS: dict[str, tuple[str, ...]] = {
    "antalate_pose": (
        "stateEstimate.x",
        "stateEstimate.y",
        "stateEstimate.z",
        "stateEstimate.vx",
        "stateEstimate.vy",
        "stateEstimate.vz",
    ),
    "antalate_status": ("stateEstimate.yaw", "pm.vbat", "pm.state", "pm.batteryLevel", "supervisor.info"),
    "antalate_estimator": ("kalman.varPX", "kalman.varPY", "kalman.varPZ"),
}

#: Bytes per log type (cflib LogTocElement.types), to keep every block within one packet.
LOG_TYPE_SIZES = {
    "uint8_t": 1,
    "int8_t": 1,
    "uint16_t": 2,
    "int16_t": 2,
    "uint32_t": 4,
    "int32_t": 4,
    "float": 4,
    "FP16": 2,
}
LOG_MAX_BYTES = 26

# supervisor.info bits
CAN_BE_ARMED, IS_ARMED, AUTO_ARMED, CAN_FLY, IS_FLYING, IS_TUMBLED, IS_LOCKED, IS_CRASHED = range(8)
HL_ACTIVE, HL_TRAJ_FINISHED, HL_DISABLED = 8, 9, 10


@dataclass(frozen=True)
class SupervisorFlags:
    """The supervisor's state bitfield, decoded."""

    can_be_armed: bool = False
    armed: bool = False
    can_fly: bool = False
    flying: bool = False
    tumbled: bool = False
    locked: bool = False
    crashed: bool = False
    hl_active: bool = False
    hl_disabled: bool = False

    @classmethod
    def from_info(cls, info: int) -> SupervisorFlags:
        def bit(n: int) -> bool:
            return bool(info >> n & 1)

        return cls(
            bit(CAN_BE_ARMED),
            bit(IS_ARMED),
            bit(CAN_FLY),
            bit(IS_FLYING),
            bit(IS_TUMBLED),
            bit(IS_LOCKED),
            bit(IS_CRASHED),
            bit(HL_ACTIVE),
            bit(HL_DISABLED),
        )

    def arm_blocker(self) -> str:
        """Why the supervisor will not arm (or fly), empty when nothing in the bitfield stops it."""
        if self.locked:
            return (
                "the supervisor is locked (after an emergency stop, a crash or a commander watchdog "
                "timeout): reboot the Crazyflie"
            )
        if self.crashed:
            return "the supervisor reports a crash: send a crash recovery or reboot the Crazyflie"
        if self.tumbled:
            return "the Crazyflie is tumbled (upside down or tilted): put it upright"
        return ""


@dataclass(frozen=True)
class Reading:
    """The latest values of every logged variable; NaN / -1 until first received."""

    x: float = math.nan
    y: float = math.nan
    z: float = math.nan
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    yaw: float = 0.0  # deg, counter-clockwise
    vbat: float = math.nan  # V
    pm_state: int = -1
    battery_level: int = -1  # percent in steps of 10 (the firmware's charge curve)
    info: int = 0
    var_x: float = math.inf
    var_y: float = math.inf
    var_z: float = math.inf

    @property
    def flags(self) -> SupervisorFlags:
        return SupervisorFlags.from_info(self.info)

    @property
    def has_pose(self) -> bool:
        return math.isfinite(self.x) and math.isfinite(self.y) and math.isfinite(self.z)


_FIELDS = {
    "stateEstimate.x": ("x", float),
    "stateEstimate.y": ("y", float),
    "stateEstimate.z": ("z", float),
    "stateEstimate.vx": ("vx", float),
    "stateEstimate.vy": ("vy", float),
    "stateEstimate.vz": ("vz", float),
    "stateEstimate.yaw": ("yaw", float),
    "pm.vbat": ("vbat", float),
    "pm.state": ("pm_state", int),
    "pm.batteryLevel": ("battery_level", int),
    "supervisor.info": ("info", int),
    "kalman.varPX": ("var_x", float),
    "kalman.varPY": ("var_y", float),
    "kalman.varPZ": ("var_z", float),
}


def apply_log(reading: Reading, data: dict[str, Any]) -> Reading:
    """`reading` updated with one log packet's ``{name: value}``; unknown names and bad values ignored.

    A non-finite float (a diverged estimator sends NaN) is kept for the variances -- it means "not
    converged" -- but never replaces a position or velocity: the last finite one is a better guess
    than NaN propagated into WGS84.
    """
    changes: dict[str, Any] = {}
    for name, value in data.items():
        spec = _FIELDS.get(name)
        if spec is None:
            continue
        attr, kind = spec
        try:
            converted = kind(value)
        except (TypeError, ValueError, OverflowError):
            continue
        if kind is float and not math.isfinite(converted) and not attr.startswith("var_"):
            continue
        changes[attr] = converted
    if not changes:
        return reading
    return Reading(**{**reading.__dict__, **changes})


def estimator_problem(reading: Reading, max_variance: float) -> str:
    """Why the position estimate is not good enough to fly on; empty when it is.

    The Kalman filter's position variances shrink once its sensors (Lighthouse, Loco, Flow, mocap)
    agree; cflib's ``reset_estimator`` waits for the same thing. Flying before that drifts or flips.
    """
    if not reading.has_pose:
        return "no position estimate received yet (stateEstimate)"
    variances = {"x": reading.var_x, "y": reading.var_y, "z": reading.var_z}
    bad = {k: v for k, v in variances.items() if not (math.isfinite(v) and v <= max_variance)}
    if bad:
        shown = ", ".join(f"var{k.upper()} {v:.3g}" for k, v in bad.items())
        return (
            f"the position estimator has not converged ({shown} > max_position_variance "
            f"{max_variance:g} m^2): check the positioning system (Lighthouse base stations, Loco "
            f"anchors, Flow deck, motion capture) and reset the estimator"
        )
    return ""


def battery_warning(pm_state: int) -> str:
    """The firmware's own battery verdict from ``pm.state``; empty when it has none."""
    if pm_state == 3:
        return "pm.state lowPower (battery below the firmware's low voltage)"
    if pm_state == 4:
        return "pm.state shutDown (battery critical)"
    return ""


def block_size(types: list[str]) -> int:
    """Bytes a log block of these C types takes in a log packet (must be <= `LOG_MAX_BYTES`)."""
    return sum(LOG_TYPE_SIZES[t] for t in types)
