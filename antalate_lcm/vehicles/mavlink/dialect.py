"""ArduCopter's MAVLink dialect as the adapter speaks it: mode numbers, masks, names and messages (pure).

Everything here is a table or a function of its arguments: no link, no clock, no thread. The messages
are pymavlink message objects (the MAVLink 2 ``ardupilotmega`` dialect); a link (`link.MavLink`) frames
them, so the same message goes over a serial port, UDP, TCP or a `link.MemoryLink` in a test.
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import Frame

#: ArduCopter mode numbers (HEARTBEAT custom_mode) by name, from pymavlink's table.
COPTER_MODES: dict[str, int] = {name: number for number, name in mavutil.mode_mapping_acm.items()}
_MODE_NAMES: dict[int, str] = dict(mavutil.mode_mapping_acm)

#: Velocity + yaw rate: ignore position, acceleration and yaw (bits set = ignored).
VELOCITY_TYPE_MASK = (
    mav.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_Z_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
)
#: antalate's velocity frames on the wire.
FRAMES: dict[Frame, int] = {Frame.NED: mav.MAV_FRAME_LOCAL_NED, Frame.BODY: mav.MAV_FRAME_BODY_OFFSET_NED}

#: EKF_STATUS_REPORT: what "the EKF uses GPS" means here.
EKF_NEEDED = mav.EKF_ATTITUDE | mav.EKF_VELOCITY_HORIZ | mav.EKF_POS_HORIZ_ABS
EKF_FORBIDDEN = mav.EKF_CONST_POS_MODE | mav.EKF_UNINITIALIZED

#: EXTENDED_SYS_STATE landed states that count as flying.
IN_AIR = frozenset({mav.MAV_LANDED_STATE_IN_AIR, mav.MAV_LANDED_STATE_TAKEOFF, mav.MAV_LANDED_STATE_LANDING})
#: HEARTBEAT system_status values of a flying ArduCopter (without EXTENDED_SYS_STATE).
FLYING_STATUS = frozenset({mav.MAV_STATE_ACTIVE, mav.MAV_STATE_CRITICAL, mav.MAV_STATE_EMERGENCY})
#: HEARTBEAT types that are never the autopilot, even from component 1.
NOT_AUTOPILOT_TYPES = frozenset(
    {
        mav.MAV_TYPE_GCS,
        mav.MAV_TYPE_ONBOARD_CONTROLLER,
        mav.MAV_TYPE_GIMBAL,
        mav.MAV_TYPE_ADSB,
        mav.MAV_TYPE_CAMERA,
        mav.MAV_TYPE_ANTENNA_TRACKER,
    }
)

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
#: Where the COMMAND_ACK of a SET_MODE *message* is filed: ArduPilot answers it with this "command".
SET_MODE_ACK = mav.MAVLINK_MSG_ID_SET_MODE


def mode_name(custom_mode: int) -> str:
    """ArduCopter's name for a HEARTBEAT ``custom_mode`` (``MODE_<n>`` for one pymavlink does not know)."""
    return _MODE_NAMES.get(custom_mode, f"MODE_{custom_mode}")


def result_name(result: int | None) -> str:
    if result is None:
        return "no COMMAND_ACK"
    entry = mav.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else f"result {result}"


def cmd_name(command: int) -> str:
    entry = mav.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"command {command}"


def status_name(status: int | None) -> str:
    if status is None:
        return "unknown"
    entry = mav.enums["MAV_STATE"].get(status)
    return entry.name.removeprefix("MAV_STATE_") if entry is not None else str(status)


def text(raw: Any, encoding: str = "utf-8") -> str:
    """A char[] field as text: pymavlink gives ``str`` or ``bytes`` depending on the version and dialect."""
    value = raw if isinstance(raw, str) else bytes(raw).decode(encoding, "replace")
    return value.rstrip("\x00")


def is_autopilot(msg: Any, target_system: int, target_component: int) -> bool:
    """Whether HEARTBEAT `msg` comes from the autopilot to talk to (0 = any system / component 1)."""
    want_comp = target_component or mav.MAV_COMP_ID_AUTOPILOT1
    return bool(
        msg.autopilot != mav.MAV_AUTOPILOT_INVALID
        and msg.type not in NOT_AUTOPILOT_TYPES
        and msg.get_srcComponent() == want_comp
        and target_system in (0, msg.get_srcSystem())
    )


# ---------------------------------------------------------------------- messages the adapter sends


def gcs_heartbeat() -> Any:
    """Our HEARTBEAT: a ground station (ArduCopter's GCS failsafe watches for it)."""
    return mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE, 3
    )


def velocity_target(
    target: tuple[int, int], boot_ms: int, frame: int, vx: float, vy: float, vz: float, yaw_rate: float
) -> Any:
    """SET_POSITION_TARGET_LOCAL_NED with velocity and yaw rate only; `yaw_rate` in deg/s (rad/s on the wire)."""
    return mav.MAVLink_set_position_target_local_ned_message(
        boot_ms & 0xFFFFFFFF,
        target[0],
        target[1],
        frame,
        VELOCITY_TYPE_MASK,
        0,
        0,
        0,
        vx,
        vy,
        vz,
        0,
        0,
        0,
        0,
        math.radians(yaw_rate),
    )


def command_long(target: tuple[int, int], command: int, confirmation: int, *params: float) -> Any:
    """COMMAND_LONG with up to seven parameters (the rest 0)."""
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    return mav.MAVLink_command_long_message(target[0], target[1], command, confirmation, *p)


def set_mode(target_system: int, custom_mode: int) -> Any:
    """The SET_MODE message: the fallback for firmware without MAV_CMD_DO_SET_MODE."""
    return mav.MAVLink_set_mode_message(target_system, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)


def request_data_stream(target: tuple[int, int], stream: int, hz: int) -> Any:
    return mav.MAVLink_request_data_stream_message(target[0], target[1], stream, hz, 1)


def param_request_read(target: tuple[int, int], name: str) -> Any:
    return mav.MAVLink_param_request_read_message(target[0], target[1], name.encode("ascii"), -1)


def param_set(target: tuple[int, int], name: str, value: float, param_type: int) -> Any:
    return mav.MAVLink_param_set_message(target[0], target[1], name.encode("ascii"), float(value), param_type)
