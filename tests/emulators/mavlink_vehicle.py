"""An ArduCopter-like MAVLink 2 vehicle over UDP and TCP, so tests can drive the real pymavlink client.

It speaks ArduCopter's dialect of the things the ``mavlink`` autopilot adapter relies on, with the
quirks a real flight controller has, so adapter code that passes here is ready for SITL or hardware:

Identity and heartbeat
    System 1, component 1 (MAV_COMP_ID_AUTOPILOT1), ``MAV_TYPE_QUADROTOR``, ``MAV_AUTOPILOT_ARDUPILOTMEGA``,
    ``custom_mode`` = ArduCopter mode number (:data:`COPTER_MODES`). HEARTBEAT at 1 Hz with
    ``system_status`` BOOT then CALIBRATING during ``boot_delay``, then STANDBY (ACTIVE while armed).
    ``base_mode`` carries CUSTOM_MODE_ENABLED, and SAFETY_ARMED while armed (what ``mavutil`` reads).
Boot, EKF, GPS (all delays count from ``start()``)
    A mode set during boot is acknowledged ACCEPTED and then silently reverted to ``initial_mode`` when
    boot ends (a real ArduCopter start-up quirk). GPS_RAW_INT has ``fix_type`` 0 until ``gps_delay``,
    then 3. EKF_STATUS_REPORT has no horizontal position flags until ``ekf_delay`` passed *and* the GPS
    has a fix; GLOBAL_POSITION_INT reports lat/lon 0 until then. Home is set when the position first
    becomes valid, and again at arming.
Arming (MAV_CMD_COMPONENT_ARM_DISARM)
    Refused (COMMAND_ACK FAILED, plus a ``PreArm:`` STATUSTEXT) during boot, without GPS fix or EKF
    position, in a mode that cannot arm (RTL, LAND, ...), or while the ``refuse_arm`` fault is set.
    ``param2 = 21196`` forces it (not past ``refuse_arm``). Disarm is refused in flight unless forced.
    An armed copter that does not take off disarms itself after ``disarm_delay`` (10 s, DISARM_DELAY).
Modes
    Via the SET_MODE message (acknowledged with COMMAND_ACK whose ``command`` is 11, the SET_MODE message
    id, as ArduPilot does) or MAV_CMD_DO_SET_MODE. Modes needing a position (GUIDED, LOITER, RTL, ...)
    are refused without one. AUTO is refused: the emulator holds no mission.
Flying
    MAV_CMD_NAV_TAKEOFF (altitude in param7) only in GUIDED, armed and on the ground; climbs at
    ``climb_rate``. SET_POSITION_TARGET_LOCAL_NED in GUIDED: velocity targets (+ yaw rate or yaw) in
    LOCAL_NED / LOCAL_OFFSET_NED or, rotated by the heading, BODY_NED / BODY_OFFSET_NED; position
    targets too. The velocity follows with a first-order lag (``velocity_tau``); without a new target
    for GUID_TIMEOUT (``guided_timeout``, 3 s) the copter stops. A velocity target during the takeoff climb ends the
    takeoff, as in ArduCopter. Targets are ignored on the ground and outside GUIDED. RTL climbs to
    ``rtl_alt`` if set (0 = return at the current altitude), flies home at ``rtl_speed``, lands and
    disarms; LAND descends (``land_speed_high`` above ``land_alt_low``, then ``land_speed``) and
    disarms ``land_detect_time`` after touching down. Every other mode hovers. MAV_CMD_NAV_LAND and
    MAV_CMD_NAV_RETURN_TO_LAUNCH switch to LAND/RTL; MAV_CMD_CONDITION_YAW turns in GUIDED.
Telemetry
    GLOBAL_POSITION_INT (lat/lon 1e7 deg, ``alt`` mm AMSL, ``relative_alt`` mm above home, vx/vy/vz
    cm/s NED, ``hdg`` cdeg), ATTITUDE, SYS_STATUS (``battery_remaining`` drains by ``battery_drain``
    %/s while armed), EXTENDED_SYS_STATE (``landed_state`` ON_GROUND, TAKEOFF, IN_AIR, LANDING),
    GPS_RAW_INT, EKF_STATUS_REPORT, VFR_HUD, LOCAL_POSITION_NED, HOME_POSITION, SYSTEM_TIME, STATUSTEXT.
    Default rates are :data:`DEFAULT_RATES` (override with ``stream_rates``); REQUEST_DATA_STREAM and
    MAV_CMD_SET_MESSAGE_INTERVAL change them; MAV_CMD_REQUEST_MESSAGE / GET_HOME_POSITION /
    REQUEST_AUTOPILOT_CAPABILITIES send one message. Every COMMAND_LONG / COMMAND_INT addressed to the
    vehicle gets a COMMAND_ACK (unknown commands: UNSUPPORTED).

Position integrates in a local NED frame whose origin is ``home_lat/home_lon`` (flat-earth conversion to
lat/lon). Speeds default to values faster than ArduCopter's (LAND_SPEED 0.5 m/s, LAND_ALT_LOW 10 m) so a
whole mission takes seconds in tests; every one is a constructor argument.

Transports: ``udp_port`` (0 = a free port) answers every peer that sends it something (pymavlink
``udpout:HOST:PORT``; the client must send first, e.g. a HEARTBEAT); ``udp_target=(host, port)`` also
pushes to a fixed address like SITL's ``udpclient`` (pymavlink ``udpin:HOST:PORT``); ``tcp_port``
accepts any number of TCP clients (pymavlink ``tcp:HOST:PORT``). Ports are read back from
``udp_port``/``tcp_port`` after ``start()``. ``memory_link()`` adds a client without a socket: an
``antalate_lcm.vehicles.mavlink.link.MemoryLink`` whose frames reach the vehicle as bytes, like a TCP
client's (``udp_port=None`` for a vehicle with no socket at all).

Parameters (:data:`PARAMS`, ArduCopter 4.x names, defaults and types; ``params={...}`` overrides)
    PARAM_REQUEST_READ (by name or index), PARAM_REQUEST_LIST and PARAM_SET answered with PARAM_VALUE,
    as ArduPilot does (an unknown name gets no answer). They drive the failsafes below.
    ``gcs_sysid_param="MAV_GCS_SYSID"`` names the GCS id parameter as Copter 4.7 does.
Failsafes (modelled on ArduCopter's events.cpp, fence.cpp, ekf_check.cpp and AP_BattMonitor)
    GCS: with FS_GCS_ENABLE != 0, once a HEARTBEAT from system SYSID_MYGCS was heard, FS_GCS_TIMEOUT s
    without one -> "GCS Failsafe" and the FS_GCS_ENABLE action (1 RTL, 5 LAND, 7 BRAKE; 3/4/6 -> RTL),
    disarm if armed on the ground; "GCS Failsafe Cleared" when heartbeats return. GUID_TIMEOUT: a
    velocity target older than it -> the copter stops. Fence: FENCE_ENABLE with a circle of FENCE_RADIUS
    around home and FENCE_ALT_MAX; a new breach while armed -> FENCE_STATUS breach, the SYS_STATUS
    GEOFENCE health bit cleared, "Fence Breached" and the FENCE_ACTION (1/3/5 RTL, 2 LAND, 4 BRAKE,
    0 report only). Battery: voltage below BATT_LOW_VOLT for BATT_LOW_TIMER s (or below BATT_CRT_VOLT)
    -> BATTERY_STATUS charge_state LOW/CRITICAL, SYS_STATUS BATTERY unhealthy, "Battery 1 is low
    10.40V used 0 mAh" and the BATT_FS_LOW_ACT / BATT_FS_CRT_ACT action (1 LAND, 2/3/4 RTL, 5 disarm).
    EKF: ``fail_ekf()`` -> variances above FS_EKF_THRESH, SYS_STATUS AHRS unhealthy, after 1 s
    "EKF variance" and the FS_EKF_ACTION (1 LAND if the mode needs a position, 2 ALT_HOLD, 3 LAND).
Battery telemetry
    SYS_STATUS ``voltage_battery`` and BATTERY_STATUS: the pack voltage in ``voltages[0]`` (ArduPilot's
    analog monitors) or, with ``per_cell_monitor=True``, one entry per cell of ``battery_cells``;
    ``report_remaining=False`` sends ``battery_remaining`` -1 as many real vehicles do.
MAVLink 2 signing
    ``signing_key=<32 bytes>``: everything sent is signed; unsigned or badly signed messages are dropped
    and counted (``signing_rejected``), except RADIO_STATUS, as ArduPilot does.

Not emulated: missions, RC input, SmartRTL (its failsafe options fly RTL).

Faults: ``stop_heartbeats()`` (the link goes silent both ways: nothing is sent, nothing is received)
and ``resume_heartbeats()``; ``drop_uplink()`` (only the ground-to-vehicle direction is lost);
``cut_link()`` / ``restore_link()`` (a TCP link or buffering radio: during
the cut nothing is delivered either way but everything is kept, and delivered at once on restore);
``refuse_arm = True``; ``pilot_switch_mode("LOITER")`` (an RC mode switch: no COMMAND_ACK, guided
targets dropped); ``set_battery(pct)``; ``set_voltage(volts)``; ``fail_ekf()``; ``inject(msg, key)``
(a message from someone else on the link: unsigned, or signed with another key).

CLI (to run it as a separate process, e.g. in a network namespace)::

    python -m tests.emulators.mavlink_vehicle --host 127.0.0.1 --udp-port 14550 --tcp-port 5760

prints ``READY udp=<port> tcp=<port>`` once listening and, on SIGTERM/SIGINT, a JSON snapshot with the
failsafe actions taken (``failsafe_modes``) and every STATUSTEXT sent.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import select
import signal
import socket
import struct
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav2

from antalate_lcm.vehicles.mavlink.link import MemoryLink
from tests.emulators.lifecycle import Emulator

LOG = logging.getLogger("antalate.tests.mavlink_vehicle")

#: pymavlink's dialect ships no types: the enum values the emulator returns, typed once here.
MAV_LANDED_STATE_IN_AIR: int = mav2.MAV_LANDED_STATE_IN_AIR
MAV_LANDED_STATE_LANDING: int = mav2.MAV_LANDED_STATE_LANDING
MAV_LANDED_STATE_ON_GROUND: int = mav2.MAV_LANDED_STATE_ON_GROUND
MAV_LANDED_STATE_TAKEOFF: int = mav2.MAV_LANDED_STATE_TAKEOFF
MAV_RESULT_ACCEPTED: int = mav2.MAV_RESULT_ACCEPTED
MAV_RESULT_DENIED: int = mav2.MAV_RESULT_DENIED
MAV_RESULT_FAILED: int = mav2.MAV_RESULT_FAILED
MAV_RESULT_UNSUPPORTED: int = mav2.MAV_RESULT_UNSUPPORTED
MAV_STATE_ACTIVE: int = mav2.MAV_STATE_ACTIVE
MAV_STATE_BOOT: int = mav2.MAV_STATE_BOOT
MAV_STATE_CALIBRATING: int = mav2.MAV_STATE_CALIBRATING
MAV_STATE_STANDBY: int = mav2.MAV_STATE_STANDBY


Address = tuple[str, int]

#: Short start-up and brisk kinematics, heartbeats at 10 Hz: the copter the end-to-end and security
#: tests fly, so a whole sortie takes seconds (one profile, shared by the in-process and process tests).
BRISK: dict[str, Any] = {
    "boot_delay": 0.2,
    "ekf_delay": 0.3,
    "gps_delay": 0.3,
    "heartbeat_rate": 10.0,
    "climb_rate": 4.0,
    "max_climb_rate": 4.0,
    "land_speed": 2.5,
    "land_speed_high": 3.0,
    "max_descent_rate": 3.0,
    "rtl_speed": 8.0,
    "velocity_tau": 0.15,
    "land_detect_time": 0.2,
}

#: ArduCopter 4.6.3 (SITL, copter.parm) as it flies: WPNAV_SPEED_UP 2.5 m/s, WPNAV_SPEED_DN 1.5 m/s above
#: LAND_ALT_LOW 10 m, LAND_SPEED 0.5 m/s below, WPNAV_SPEED 10 m/s home, RTL_ALT 15 m, RTL_LOIT_TIME 5 s,
#: the land detector's ~1 s; the boot is seconds, not SITL's ~40 s (nothing compared depends on it).
#: The profile the comparison tests (tests/sitl_arducopter/test_failsafes.py) fly against the firmware.
ARDUCOPTER: dict[str, Any] = {
    "boot_delay": 1.0,
    "ekf_delay": 3.0,
    "gps_delay": 2.0,
    "climb_rate": 2.5,
    "max_climb_rate": 2.5,
    "land_speed": 0.5,
    "land_speed_high": 1.5,
    "land_alt_low": 10.0,
    "max_descent_rate": 1.5,
    "rtl_speed": 10.0,
    "rtl_alt": 15.0,
    "rtl_loiter_time": 5.0,
    "velocity_tau": 0.5,
    "land_detect_time": 1.0,
    "battery_drain": 0.0,
}

COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "DRIFT": 11,
    "SPORT": 13,
    "FLIP": 14,
    "AUTOTUNE": 15,
    "POSHOLD": 16,
    "BRAKE": 17,
    "THROW": 18,
    "AVOID_ADSB": 19,
    "GUIDED_NOGPS": 20,
    "SMART_RTL": 21,
    "FLOWHOLD": 22,
    "FOLLOW": 23,
    "ZIGZAG": 24,
    "SYSTEMID": 25,
    "AUTOROTATE": 26,
    "AUTO_RTL": 27,
}
MODE_NAMES: dict[int, str] = {number: name for name, number in COPTER_MODES.items()}
# Modes that need a position estimate to be entered.
POSITION_MODES = frozenset(
    {
        "AUTO",
        "GUIDED",
        "LOITER",
        "RTL",
        "CIRCLE",
        "DRIFT",
        "POSHOLD",
        "BRAKE",
        "THROW",
        "AVOID_ADSB",
        "SMART_RTL",
        "FOLLOW",
        "ZIGZAG",
        "AUTO_RTL",
    }
)
# Modes ArduCopter will not arm in.
NOT_ARMABLE = frozenset(
    {"RTL", "LAND", "CIRCLE", "BRAKE", "SMART_RTL", "FLIP", "AUTOTUNE", "FOLLOW", "AUTO_RTL", "AVOID_ADSB"}
)

DEFAULT_RATES: dict[str, float] = {
    "GLOBAL_POSITION_INT": 5.0,
    "ATTITUDE": 5.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "GPS_RAW_INT": 1.0,
    "EKF_STATUS_REPORT": 1.0,
    "VFR_HUD": 2.0,
    "LOCAL_POSITION_NED": 0.0,
    "HOME_POSITION": 0.0,
    "SYSTEM_TIME": 0.0,
    "BATTERY_STATUS": 1.0,
    "FENCE_STATUS": 1.0,
}
# REQUEST_DATA_STREAM groups (ArduCopter's grouping, restricted to the messages emulated here).
DATA_STREAMS: dict[int, tuple[str, ...]] = {
    mav2.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT", "EXTENDED_SYS_STATE", "FENCE_STATUS"),
    mav2.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    mav2.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    mav2.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    mav2.MAV_DATA_STREAM_EXTRA3: ("EKF_STATUS_REPORT", "SYSTEM_TIME", "BATTERY_STATUS"),
    mav2.MAV_DATA_STREAM_RAW_SENSORS: (),
    mav2.MAV_DATA_STREAM_RC_CHANNELS: (),
    mav2.MAV_DATA_STREAM_RAW_CONTROLLER: (),
}
FORCE_MAGIC = 21196  # param2 of ARM_DISARM that bypasses checks (ArduPilot convention)

_I8, _I16, _R32 = mav2.MAV_PARAM_TYPE_INT8, mav2.MAV_PARAM_TYPE_INT16, mav2.MAV_PARAM_TYPE_REAL32
_I32 = mav2.MAV_PARAM_TYPE_INT32
#: ArduCopter 4.x parameters the emulator keeps: name -> (default, MAV_PARAM_TYPE).
PARAMS: dict[str, tuple[float, int]] = {
    "SYSID_THISMAV": (1, _I16),
    "SYSID_MYGCS": (255, _I16),
    "FS_GCS_ENABLE": (0, _I8),
    "FS_GCS_TIMEOUT": (5.0, _R32),
    "GUID_TIMEOUT": (3.0, _R32),
    "FENCE_ENABLE": (0, _I8),
    "FENCE_ACTION": (1, _I8),
    "FENCE_RADIUS": (300.0, _R32),
    "FENCE_ALT_MAX": (100.0, _R32),
    # AC_Fence.h defaults: FENCE_TYPE 7 (alt max | circle | polygon), ALT_MIN -10 m, MARGIN 2 m.
    "FENCE_TYPE": (7, _I8),
    "FENCE_ALT_MIN": (-10.0, _R32),
    "FENCE_MARGIN": (2.0, _R32),
    "BATT_MONITOR": (4, _I8),
    "BATT_LOW_VOLT": (10.5, _R32),
    "BATT_CRT_VOLT": (0.0, _R32),
    "BATT_LOW_TIMER": (10, _I8),
    "BATT_FS_LOW_ACT": (0, _I8),
    "BATT_FS_CRT_ACT": (0, _I8),
    "FS_EKF_ACTION": (1, _I8),
    "FS_EKF_THRESH": (0.8, _R32),
    "DISARM_DELAY": (10, _I8),
    # Parameters.cpp (Copter-4.6.3): FS_OPTIONS 16 = continue a GCS failsafe in pilot-controlled modes;
    # FS_THR_ENABLE 1 = radio failsafe RTL (copter.parm keeps 1). The RTL's: RTL_ALT cm (set from the
    # constructor's `rtl_alt`), RTL_CLIMB_MIN cm, RTL_LOIT_TIME ms (from `rtl_loiter_time`), RTL_CONE_SLOPE;
    # LAND_SPEED cm/s (from `land_speed`).
    "FS_OPTIONS": (16, _I32),
    "FS_THR_ENABLE": (1, _I8),
    "RTL_ALT": (1500, _I32),
    "RTL_CLIMB_MIN": (0, _I16),
    "RTL_LOIT_TIME": (5000, _I32),
    "RTL_CONE_SLOPE": (3.0, _R32),
    "LAND_SPEED": (50, _I16),
    # SITL's failure injection (libraries/SITL/SITL.cpp): the pack's voltage (applied when set), the GPS
    # switched off, the RC receiver's pulses stopped (1).
    "SIM_BATT_VOLTAGE": (12.6, _R32),
    "SIM_GPS_DISABLE": (0, _I8),
    "SIM_RC_FAIL": (0, _I8),
}
#: FS_OPTIONS bits (ArduCopter/Copter.h FailsafeOption, Copter-4.6.3).
FS_OPT_RC_CONTINUE_IF_GUIDED = 1 << 2
FS_OPT_CONTINUE_IF_LANDING = 1 << 3
FS_OPT_GCS_CONTINUE_IF_PILOT_CONTROL = 1 << 4
#: Modes whose Mode::is_autopilot() is true (ArduCopter/mode.h): the others are a pilot's.
AUTOPILOT_MODES = frozenset(
    {
        "AUTO",
        "CIRCLE",
        "GUIDED",
        "GUIDED_NOGPS",
        "LAND",
        "RTL",
        "SMART_RTL",
        "AUTO_RTL",
        "FOLLOW",
        "AVOID_ADSB",
    }
)
LAND_WITH_DELAY = 4.0  # s: mode_land.cpp LAND_WITH_DELAY_MS, the pause of a failsafe's LAND before descending
RTL_ALT_MIN = 2.0  # m: mode_rtl.cpp RTL_ALT_MIN (200 cm), the lowest an RTL returns at
RTL_MIN_CONE_SLOPE = 0.5  # mode_rtl.cpp: a smaller RTL_CONE_SLOPE turns the cone off
GPS_DEAD_RECKONING = 6.0  # s the EKF keeps a position without GPS (measured, ArduCopter 4.6.3 SITL: ~6-7 s)
_FS_GCS_MODES = {1: "RTL", 2: "RTL", 3: "RTL", 4: "RTL", 5: "LAND", 6: "RTL", 7: "BRAKE"}
_FS_THR_MODES = {1: "RTL", 2: "RTL", 3: "LAND", 4: "RTL", 5: "LAND"}  # radio.cpp / events.cpp, no SmartRTL
_FENCE_MODES = {1: "RTL", 2: "LAND", 3: "RTL", 4: "BRAKE", 5: "RTL"}
_BATT_MODES = {1: "LAND", 2: "RTL", 3: "RTL", 4: "RTL", 6: "RTL"}
_EKF_BAD_FOR = 1.0  # s of bad variances before ArduCopter's EKF failsafe (ekf_check: 10 checks at 10 Hz)
EARTH_RADIUS = 6378137.0

_EKF_GOOD = (
    mav2.EKF_ATTITUDE
    | mav2.EKF_VELOCITY_HORIZ
    | mav2.EKF_VELOCITY_VERT
    | mav2.EKF_POS_HORIZ_REL
    | mav2.EKF_POS_HORIZ_ABS
    | mav2.EKF_POS_VERT_ABS
    | mav2.EKF_POS_VERT_AGL
    | mav2.EKF_PRED_POS_HORIZ_REL
    | mav2.EKF_PRED_POS_HORIZ_ABS
)
_EKF_NO_POSITION = (
    mav2.EKF_ATTITUDE | mav2.EKF_VELOCITY_VERT | mav2.EKF_POS_VERT_ABS | mav2.EKF_CONST_POS_MODE
)
_SENSORS = (
    mav2.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mav2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mav2.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mav2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mav2.MAV_SYS_STATUS_SENSOR_GPS
)
_TM_POS = (
    mav2.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mav2.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mav2.POSITION_TARGET_TYPEMASK_Z_IGNORE
)
_TM_VEL = (
    mav2.POSITION_TARGET_TYPEMASK_VX_IGNORE
    | mav2.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | mav2.POSITION_TARGET_TYPEMASK_VZ_IGNORE
)


@dataclass(frozen=True)
class VehicleSnapshot:
    """A consistent copy of the vehicle state. Local frame: NED from the EKF origin (``home_lat/lon``)."""

    booted: bool
    system_status: int
    mode: str
    custom_mode: int
    armed: bool
    landed_state: int
    north: float
    east: float
    alt: float  # m above the origin's ground (= relative altitude while home is at the origin)
    vn: float
    ve: float
    vd: float
    yaw: float  # degrees, 0 = north, clockwise, [0, 360)
    lat: float
    lon: float
    battery: float
    gps_fix_type: int
    ekf_position_ok: bool
    home: tuple[float, float, float] | None  # lat, lon, alt AMSL
    link_up: bool
    guided_submode: str | None  # takeoff | velocity | position | hover (GUIDED only)
    rtl_phase: str | None  # climb | return | loiter | land (RTL only)
    rtl_alt: float  # m: the altitude the current (or last) RTL returns at


@dataclass(frozen=True)
class Received:
    """One message the vehicle received (for assertions)."""

    t: float  # time.monotonic()
    type: str
    fields: dict[str, Any]


class _Peer:
    """One transport endpoint with its own parser (MAVLink framing state is per stream)."""

    def __init__(
        self,
        sysid: int,
        compid: int,
        sock: socket.socket | None = None,
        addr: Address | None = None,
        key: bytes | None = None,
        link: MemoryLink | None = None,
    ):
        self.sock = sock  # TCP client socket, None for UDP peers
        self.addr = addr
        self.link = link  # the client's end of an in-memory link (`MavlinkVehicle.memory_link`)
        self.parser = mav2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser.robust_parsing = True
        self.rejected = 0  # messages dropped for their signature
        if key is not None:
            self.parser.signing.secret_key = key
            self.parser.signing.allow_unsigned_callback = lambda _mav, msg_id: (
                msg_id == mav2.MAVLINK_MSG_ID_RADIO_STATUS
            )
            self.parser.check_signature = self._check_signature

    def _check_signature(self, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        """The C library's mavlink_signature_check (what ArduPilot runs): the signature first, then the
        timestamp. pymavlink records the timestamp before comparing the signature, so one forged frame
        with a future timestamp would make every genuine one look like a replay."""
        signing = self.parser.signing
        if hashlib.sha256(bytes(signing.secret_key) + bytes(msgbuf[:-6])).digest()[:6] != bytes(msgbuf[-6:]):
            return False
        low, high = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
        timestamp = low + (high << 32)
        stream = (msgbuf[-13], src_system, src_component)
        last = signing.stream_timestamps.get(stream)
        if (last is not None and timestamp <= last) or (
            last is None and timestamp + 6_000_000 < signing.timestamp
        ):
            return False
        signing.stream_timestamps[stream] = timestamp
        signing.timestamp = max(signing.timestamp, timestamp)
        return True

    def parse(self, data: bytes) -> list[Any]:
        msgs = self.parser.parse_buffer(data) or []
        bad = [m for m in msgs if m.get_type() == "BAD_DATA"]
        self.rejected += sum(1 for m in bad if "signature" in str(getattr(m, "reason", "")))
        return [m for m in msgs if m.get_type() != "BAD_DATA"]


class _WireBuffer:
    """The "file" pymavlink's encoder writes framed messages to; the I/O thread sends them on."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.frames.append(bytes(buf))

    def take(self) -> list[bytes]:
        frames, self.frames = self.frames, []
        return frames


class MavlinkVehicle(Emulator["VehicleSnapshot"]):
    """The emulated copter; ``start()``/``stop()`` or ``with``. Every public method is thread-safe."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        udp_port: int | None = 0,
        tcp_port: int | None = None,
        *,
        udp_target: Address | None = None,
        sysid: int = 1,
        compid: int = mav2.MAV_COMP_ID_AUTOPILOT1,
        home_lat: float = -35.363262,
        home_lon: float = 149.165237,
        home_alt: float = 584.0,
        initial_mode: str = "STABILIZE",
        boot_delay: float = 0.5,
        ekf_delay: float = 1.0,
        gps_delay: float = 1.0,
        climb_rate: float = 2.5,
        land_speed: float = 1.0,
        land_speed_high: float = 1.5,
        land_alt_low: float = 2.0,
        rtl_speed: float = 5.0,
        rtl_alt: float = 0.0,
        rtl_loiter_time: float = 0.0,
        max_speed: float = 10.0,
        max_climb_rate: float = 2.5,
        max_descent_rate: float = 1.5,
        velocity_tau: float = 0.3,
        yaw_rate_max: float = 90.0,
        guided_timeout: float = 3.0,
        disarm_delay: float = 10.0,
        land_detect_time: float = 0.5,
        battery: float = 100.0,
        battery_drain: float = 0.05,
        heartbeat_rate: float = 1.0,
        stream_rates: dict[str, float] | None = None,
        tick_rate: float = 50.0,
        params: dict[str, float] | None = None,
        gcs_sysid_param: str = "SYSID_MYGCS",
        battery_cells: int = 3,
        per_cell_monitor: bool = False,
        report_remaining: bool = True,
        signing_key: bytes | None = None,
    ) -> None:
        """Nothing is bound until ``start()``. ``udp_port``/``tcp_port``: None = off, 0 = a free port."""
        if initial_mode not in COPTER_MODES:
            raise ValueError(f"unknown ArduCopter mode {initial_mode!r}")
        self.host = host
        self.udp_port = udp_port
        self.tcp_port = tcp_port
        self.udp_target = udp_target
        self.sysid, self.compid = sysid, compid
        self.origin = (home_lat, home_lon, home_alt)
        self.initial_mode = initial_mode
        self.boot_delay, self.ekf_delay, self.gps_delay = boot_delay, ekf_delay, gps_delay
        self.climb_rate = climb_rate
        self.land_speed_high, self.land_alt_low = land_speed_high, land_alt_low
        self.rtl_speed = rtl_speed
        self.max_speed, self.max_climb_rate, self.max_descent_rate = (
            max_speed,
            max_climb_rate,
            max_descent_rate,
        )
        self.velocity_tau = velocity_tau
        self.yaw_rate_max = yaw_rate_max
        self.disarm_delay = disarm_delay
        self.land_detect_time = land_detect_time
        self.battery_drain = battery_drain
        self.tick_rate = tick_rate

        self.refuse_arm = False  # fault switch: arming answers FAILED while set
        if gcs_sysid_param not in ("SYSID_MYGCS", "MAV_GCS_SYSID"):
            raise ValueError(f"gcs_sysid_param must be SYSID_MYGCS or MAV_GCS_SYSID, not {gcs_sysid_param!r}")
        table = {(gcs_sysid_param if name == "SYSID_MYGCS" else name): spec for name, spec in PARAMS.items()}
        self._params: dict[str, float] = {name: float(default) for name, (default, _t) in table.items()}
        self._param_types: dict[str, int] = {name: ptype for name, (_d, ptype) in table.items()}
        self._params["GUID_TIMEOUT"] = float(guided_timeout)
        self._params["RTL_ALT"] = float(round(rtl_alt * 100))
        self._params["RTL_LOIT_TIME"] = float(round(rtl_loiter_time * 1000))
        self._params["LAND_SPEED"] = float(round(land_speed * 100))
        self._params["SYSID_THISMAV"] = float(sysid)
        for name, value in (params or {}).items():
            if name not in self._params:
                raise ValueError(f"unknown emulated parameter {name!r}; known: {sorted(self._params)}")
            self._params[name] = float(value)
        self.gcs_sysid_param = gcs_sysid_param
        self.battery_cells = battery_cells
        self.per_cell_monitor = per_cell_monitor
        self.report_remaining = report_remaining
        self.signing_key = signing_key

        super().__init__()
        self._lock = threading.RLock()
        self._udp: socket.socket | None = None
        self._tcp: socket.socket | None = None
        self._udp_peers: dict[Address, _Peer] = {}
        self._tcp_peers: list[_Peer] = []
        self._memory_peers: list[_Peer] = []
        self._memory_in: deque[tuple[_Peer, bytes]] = deque()  # written by clients' threads, read by ours
        self._wire = _WireBuffer()
        self._encoder = mav2.MAVLink(self._wire, srcSystem=sysid, srcComponent=compid)
        if signing_key is not None:
            self._encoder.signing.secret_key = signing_key
            self._encoder.signing.sign_outgoing = True
            self._encoder.signing.timestamp = int((time.time() - 1420070400) * 1e5)
        self._outbox: list[Any] = []
        self._after_ack: list[Any] = []  # messages a command asked for go out after its COMMAND_ACK

        self._rates: dict[str, float] = {"HEARTBEAT": heartbeat_rate, **DEFAULT_RATES, **(stream_rates or {})}
        self._default_rates = dict(self._rates)
        self._next_send: dict[str, float] = {}
        self._t0 = time.monotonic()
        self._booted = False
        self._ekf_announced = False
        self._link_up = True
        self._mode = initial_mode
        self._armed = False
        self._n = self._e = self._d = 0.0
        self._vn = self._ve = self._vd = 0.0
        self._yaw = 0.0
        self._yaw_rate = 0.0  # deg/s, the current one
        self._battery = float(battery)
        self._home: tuple[float, float, float] | None = None
        self._on_ground = True
        self._ground_since = self._t0
        self._takeoff_alt: float | None = None
        self._guided: str = "hover"
        self._target_vel = (0.0, 0.0, 0.0)
        self._target_pos: tuple[float, float, float] | None = None
        self._target_yaw: float | None = None
        self._target_yaw_rate = 0.0
        self._last_target = 0.0
        self._rtl_phase: str | None = None
        self._rtl_alt = 0.0  # m: the altitude this RTL returns at (`_rtl_target_alt`)
        self._rtl_loiter_end = 0.0  # time.monotonic() the RTL's loiter over home ends
        self._land_pause_until = 0.0  # a failsafe's LAND hovers until then (LAND_WITH_DELAY)
        self._received: deque[Received] = deque(maxlen=20000)
        self._acks: list[tuple[int, int]] = []
        self._texts: list[str] = []
        self._signing_rejected_gone = 0  # rejections counted by peers since dropped
        # failsafes
        self._gcs_seen = 0.0  # time.monotonic() of the last HEARTBEAT from the GCS id (0: never)
        self._gcs_failsafe = False
        self._fence_breached = False
        self._fence_breaches = 0
        self._fence_breach_type = mav2.FENCE_BREACH_NONE
        self._fence_breach_time = 0
        self._voltage_override: float | None = None
        self._batt_low_since: float | None = None
        self._batt_failsafe = 0  # 0 none, 1 low, 2 critical (latched, as AP_BattMonitor does)
        self._batt_action = 0  # the BATT_FS_*_ACT of that failsafe
        self._ekf_bad_since: float | None = None
        self._ekf_failsafe = False
        self._gps_off_since: float | None = None  # SIM_GPS_DISABLE: when the GPS went off
        self._rc_failsafe = False
        self.failsafe_modes: list[tuple[str, str]] = []  # (failsafe, mode) actions taken, for assertions
        # link cut with buffering (cut_link / restore_link)
        self._cut = False
        self._release = False
        self._held_in: list[tuple[_Peer, bytes]] = []
        self._held_out: list[bytes] = []
        self._injected: list[bytes] = []
        self._uplink_down = False

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self) -> MavlinkVehicle:
        """Bind the transports and power on (the boot/EKF/GPS clocks start now)."""
        if self._workers.running:
            return self
        try:
            if self.udp_port is not None:
                self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self._udp.bind((self.host, self.udp_port))
                self.udp_port = self._udp.getsockname()[1]
            if self.tcp_port is not None:
                self._tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                self._tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self._tcp.bind((self.host, self.tcp_port))
                self._tcp.listen(8)
                self.tcp_port = self._tcp.getsockname()[1]
        except OSError:
            self._close_transports()
            raise
        if self.udp_target is not None:
            self._udp_peers[self.udp_target] = self._peer(addr=self.udp_target)
        with self._lock:
            self._t0 = time.monotonic()
            self._ground_since = self._t0
        self._workers.start((self._run, "mavlink-vehicle"))
        LOG.info("MAVLink vehicle udp=%s tcp=%s", self.udp_port, self.tcp_port)
        return self

    def _peer(self, sock: socket.socket | None = None, addr: Address | None = None) -> _Peer:
        return _Peer(self.sysid, self.compid, sock=sock, addr=addr, key=self.signing_key)

    @property
    def encoder(self) -> Any:
        """A pymavlink encoder for building messages to `inject` (its ``*_encode`` methods)."""
        return mav2.MAVLink(_WireBuffer(), srcSystem=self.sysid, srcComponent=self.compid)

    def memory_link(
        self,
        *,
        source_system: int = 245,
        source_component: int = mav2.MAV_COMP_ID_ONBOARD_COMPUTER,
        signing_key: bytes | None = None,
    ) -> MemoryLink:
        """A new client on an in-memory link (like a new TCP client, without a socket): what the client
        sends reaches this vehicle's I/O thread as bytes, what the vehicle sends is fed to the link."""
        peer = self._peer()

        def write(data: bytes) -> None:
            self._memory_in.append((peer, data))

        link = MemoryLink(
            write, source_system=source_system, source_component=source_component, signing_key=signing_key
        )
        peer.link = link
        with self._lock:
            self._memory_peers.append(peer)
        return link

    @property
    def udp_url(self) -> str:
        """The pymavlink connection string for the UDP server side (the client must send first)."""
        return f"udpout:{self.host}:{self.udp_port}"

    @property
    def tcp_url(self) -> str:
        return f"tcp:{self.host}:{self.tcp_port}"

    # -- observation -----------------------------------------------------------------------------

    def snapshot(self) -> VehicleSnapshot:
        with self._lock:
            now = time.monotonic()
            lat, lon = self._latlon()
            return VehicleSnapshot(
                booted=self._booted,
                system_status=self._system_status(now),
                mode=self._mode,
                custom_mode=COPTER_MODES[self._mode],
                armed=self._armed,
                landed_state=self._landed_state(),
                north=self._n,
                east=self._e,
                alt=-self._d,
                vn=self._vn,
                ve=self._ve,
                vd=self._vd,
                yaw=self._yaw % 360.0,
                lat=lat,
                lon=lon,
                battery=self._battery,
                gps_fix_type=3 if self._gps_fix(now) else 0,
                ekf_position_ok=self._position_ok(now),
                home=self._home,
                link_up=self._link_up,
                guided_submode=self._guided if self._mode == "GUIDED" else None,
                rtl_phase=self._rtl_phase if self._mode == "RTL" else None,
                rtl_alt=self._rtl_alt,
            )

    @property
    def received(self) -> list[Received]:
        """Messages received so far (oldest first, the last 20000), a copy."""
        with self._lock:
            return list(self._received)

    def received_of(self, msg_type: str) -> list[Received]:
        return [r for r in self.received if r.type == msg_type]

    @property
    def acks(self) -> list[tuple[int, int]]:
        """(command, result) of every COMMAND_ACK sent, oldest first."""
        with self._lock:
            return list(self._acks)

    @property
    def statustexts(self) -> list[str]:
        with self._lock:
            return list(self._texts)

    def param(self, name: str) -> float:
        with self._lock:
            return self._params[name]

    @property
    def signing_rejected(self) -> int:
        """Messages dropped for a missing or wrong signature (with ``signing_key``)."""
        with self._lock:
            peers = [*self._udp_peers.values(), *self._tcp_peers, *self._memory_peers]
            return self._signing_rejected_gone + sum(p.rejected for p in peers)

    @property
    def fence_breached(self) -> bool:
        with self._lock:
            return self._fence_breached

    @property
    def gcs_failsafe(self) -> bool:
        with self._lock:
            return self._gcs_failsafe

    def voltage(self) -> float:
        with self._lock:
            return self._voltage()

    # -- fault injection -------------------------------------------------------------------------

    def stop_heartbeats(self) -> None:
        """Link loss: stop every output (heartbeats included) and drop every input until resumed."""
        with self._lock:
            self._link_up = False

    def resume_heartbeats(self) -> None:
        with self._lock:
            self._link_up = True

    def drop_uplink(self, down: bool = True) -> None:
        """An asymmetric radio link: nothing from the ground arrives (True), telemetry still goes out."""
        with self._lock:
            self._uplink_down = down

    def cut_link(self) -> None:
        """A TCP link or buffering radio cut: nothing is delivered either way, everything is kept."""
        with self._lock:
            self._cut = True

    def restore_link(self) -> None:
        """End the cut: the backlog of both directions is delivered at once (by the I/O thread)."""
        with self._lock:
            self._cut = False
            self._release = True

    def set_voltage(self, volts: float | None) -> None:
        """Pin the pack voltage (None: follow the percentage again, 12.6 V full to 9.6 V empty for 3S)."""
        with self._lock:
            self._voltage_override = None if volts is None else float(volts)

    def fail_ekf(self, failed: bool = True) -> None:
        """EKF variances above FS_EKF_THRESH (True) or back to normal (False)."""
        with self._lock:
            self._ekf_bad_since = time.monotonic() if failed else None

    def inject(self, msg: Any, key: bytes | None = None, sysid: int | None = None) -> None:
        """Send `msg` as someone else on the link would: unsigned, or signed with `key` (not ours)."""
        wire = _WireBuffer()
        enc = mav2.MAVLink(wire, srcSystem=self.sysid if sysid is None else sysid, srcComponent=self.compid)
        if key is not None:
            enc.signing.secret_key = key
            enc.signing.sign_outgoing = True
            enc.signing.timestamp = int((time.time() - 1420070400) * 1e5)
        enc.send(msg)
        with self._lock:
            self._injected.extend(wire.take())

    def pilot_switch_mode(self, mode: str) -> bool:
        """A pilot's RC mode switch: no COMMAND_ACK; GUIDED targets are dropped. False if refused."""
        with self._lock:
            return self._set_mode(mode.upper(), time.monotonic(), source="pilot") == MAV_RESULT_ACCEPTED

    def set_param(self, name: str, value: float) -> None:
        """A parameter set as a PARAM_SET from a ground station sets it (SIM_* failures included)."""
        with self._lock:
            if name not in self._params:
                raise ValueError(f"unknown emulated parameter {name!r}")
            self._apply_param(name, float(value), time.monotonic())

    def set_battery(self, pct: float) -> None:
        with self._lock:
            self._battery = max(0.0, min(100.0, float(pct)))

    # -- state helpers (lock held) -----------------------------------------------------------------

    def _gps_fix(self, now: float) -> bool:
        return now - self._t0 >= self.gps_delay and self._gps_off_since is None

    def _gps_lost(self, now: float) -> bool:
        """SIM_GPS_DISABLE for longer than the EKF dead-reckons: no position any more."""
        return self._gps_off_since is not None and now - self._gps_off_since >= GPS_DEAD_RECKONING

    def _position_ok(self, now: float) -> bool:
        if self._gps_off_since is not None:
            return self._ekf_announced and not self._gps_lost(now)
        return self._booted and self._gps_fix(now) and now - self._t0 >= self.ekf_delay

    def _landing(self) -> bool:
        """Mode::is_landing(): LAND, or an RTL in its final descent (mode_rtl.cpp)."""
        return self._mode == "LAND" or (self._mode == "RTL" and self._rtl_phase == "land")

    def _land_complete(self) -> bool:
        return self._on_ground and self._takeoff_alt is None

    def _system_status(self, now: float) -> int:
        if not self._booted:
            return MAV_STATE_BOOT if now - self._t0 < self.boot_delay / 2 else MAV_STATE_CALIBRATING
        return MAV_STATE_ACTIVE if self._armed else MAV_STATE_STANDBY

    def _landed_state(self) -> int:
        if not self._armed or (self._on_ground and self._takeoff_alt is None):
            return MAV_LANDED_STATE_ON_GROUND
        if self._mode == "GUIDED" and self._guided == "takeoff":
            return MAV_LANDED_STATE_TAKEOFF
        if self._mode == "LAND" or (self._mode == "RTL" and self._rtl_phase == "land"):
            return MAV_LANDED_STATE_LANDING
        return MAV_LANDED_STATE_IN_AIR

    def _latlon(self, n: float | None = None, e: float | None = None) -> tuple[float, float]:
        n = self._n if n is None else n
        e = self._e if e is None else e
        lat0, lon0, _ = self.origin
        lat = lat0 + math.degrees(n / EARTH_RADIUS)
        lon = lon0 + math.degrees(e / (EARTH_RADIUS * math.cos(math.radians(lat0))))
        return lat, lon

    def _home_ned(self) -> tuple[float, float]:
        if self._home is None:
            return (0.0, 0.0)
        lat0, lon0, _ = self.origin
        n = math.radians(self._home[0] - lat0) * EARTH_RADIUS
        e = math.radians(self._home[1] - lon0) * EARTH_RADIUS * math.cos(math.radians(lat0))
        return (n, e)

    def _text(self, text: str, severity: int = mav2.MAV_SEVERITY_INFO) -> None:
        self._texts.append(text)
        self._outbox.append(self._encoder.statustext_encode(severity, text.encode()[:50]))

    def _set_home_here(self) -> None:
        lat, lon = self._latlon()
        self._home = (lat, lon, self.origin[2] - self._d)
        self._outbox.append(self._make("HOME_POSITION", time.monotonic()))

    # -- modes, arming, takeoff (lock held) ----------------------------------------------------------

    def _set_mode(self, mode: str, now: float, source: str) -> int:
        if mode not in COPTER_MODES:
            return MAV_RESULT_FAILED
        if self._booted:
            if mode in POSITION_MODES and not self._position_ok(now):
                self._text(f"Flight mode change failed: {mode} requires position", mav2.MAV_SEVERITY_WARNING)
                return MAV_RESULT_FAILED
            if mode == "AUTO":
                self._text("Flight mode change failed: no mission", mav2.MAV_SEVERITY_WARNING)
                return MAV_RESULT_FAILED
        LOG.info("mode %s -> %s (%s)", self._mode, mode, source)
        self._mode = mode
        self._guided = "hover"
        self._target_vel = (0.0, 0.0, 0.0)
        self._target_pos = None
        self._target_yaw = None
        self._target_yaw_rate = 0.0
        self._rtl_phase = "climb" if mode == "RTL" else None
        if mode == "RTL":
            self._rtl_alt = self._rtl_target_alt()
        self._land_pause_until = 0.0
        self._takeoff_alt = None  # a mode change ends a guided takeoff
        return MAV_RESULT_ACCEPTED

    def _rtl_target_alt(self) -> float:
        """The altitude an RTL returns at (mode_rtl.cpp ModeRTL::compute_return_target, Copter-4.6.3):
        RTL_ALT, but at least the current altitude + RTL_CLIMB_MIN and RTL_ALT_MIN; near home the cone
        (RTL_CONE_SLOPE x the distance home) lowers it, never below that minimum."""
        alt = -self._d
        min_alt = max(RTL_ALT_MIN, alt + max(0.0, self._params["RTL_CLIMB_MIN"] / 100.0))
        target = max(self._params["RTL_ALT"] / 100.0, min_alt)
        slope = self._params["RTL_CONE_SLOPE"]
        if slope >= RTL_MIN_CONE_SLOPE:
            hn, he = self._home_ned()
            target = min(target, max(math.hypot(self._n - hn, self._e - he) * slope, min_alt))
        return target

    def _arm(self, force: bool, now: float) -> int:
        if self.refuse_arm:
            self._text("PreArm: fault injected (refuse_arm)", mav2.MAV_SEVERITY_CRITICAL)
            return MAV_RESULT_FAILED
        if not self._booted:
            self._text("PreArm: System not initialised", mav2.MAV_SEVERITY_CRITICAL)
            return MAV_RESULT_FAILED
        if self._armed:
            return MAV_RESULT_ACCEPTED
        if self._mode in NOT_ARMABLE:
            self._text("Arm: Mode not armable", mav2.MAV_SEVERITY_CRITICAL)
            return MAV_RESULT_FAILED
        if not force:
            if not self._gps_fix(now):
                self._text("PreArm: GPS 1: Bad fix", mav2.MAV_SEVERITY_CRITICAL)
                return MAV_RESULT_FAILED
            if not self._position_ok(now):
                self._text("PreArm: Need Position Estimate", mav2.MAV_SEVERITY_CRITICAL)
                return MAV_RESULT_FAILED
        self._armed = True
        self._ground_since = now
        if self._position_ok(now):
            self._set_home_here()
        self._text("Arming motors")
        return MAV_RESULT_ACCEPTED

    def _disarm(self, reason: str) -> None:
        if not self._armed:
            return
        self._armed = False
        self._takeoff_alt = None
        self._vn = self._ve = self._vd = 0.0
        self._d = 0.0  # disarmed in the air (forced), it falls
        self._on_ground = True
        self._text(f"Disarming motors ({reason})")

    def _takeoff(self, alt: float, now: float) -> int:
        if self._mode != "GUIDED" or not self._armed or not self._on_ground or alt <= 0:
            return MAV_RESULT_FAILED
        self._takeoff_alt = alt
        self._guided = "takeoff"
        return MAV_RESULT_ACCEPTED

    # -- message handling (I/O thread, lock held) ----------------------------------------------------

    def _handle(self, msg: Any, now: float) -> None:
        mtype = msg.get_type()
        self._received.append(Received(now, mtype, msg.to_dict()))
        handler = self._HANDLERS.get(mtype)
        if handler is not None:
            handler(self, msg, now)

    def _for_me(self, msg: Any, with_component: bool = True) -> bool:
        if msg.target_system not in (0, self.sysid):
            return False
        return not with_component or msg.target_component in (0, self.compid)

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self._acks.append((command, result))
        self._outbox.append(
            self._encoder.command_ack_encode(
                command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )

    def _on_set_mode(self, msg: Any, now: float) -> None:
        if not self._for_me(msg, with_component=False):
            return
        if not msg.base_mode & mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self._ack(msg, mav2.MAVLINK_MSG_ID_SET_MODE, MAV_RESULT_FAILED)
            return
        name = MODE_NAMES.get(msg.custom_mode, "")
        self._ack(msg, mav2.MAVLINK_MSG_ID_SET_MODE, self._set_mode(name, now, "SET_MODE"))

    def _on_command(self, msg: Any, now: float) -> None:
        if not self._for_me(msg):
            return
        if msg.get_type() == "COMMAND_INT":
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
        else:
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._ack(msg, msg.command, self._command(msg.command, params, now))
        self._outbox.extend(self._after_ack)
        self._after_ack.clear()

    def _command(self, cmd: int, p: tuple[float, ...], now: float) -> int:
        if cmd == mav2.MAV_CMD_COMPONENT_ARM_DISARM:
            force = round(p[1]) == FORCE_MAGIC
            if p[0] >= 0.5:
                return self._arm(force, now)
            if self._armed and not self._on_ground and not force:
                self._text("Disarm: vehicle is flying", mav2.MAV_SEVERITY_WARNING)
                return MAV_RESULT_FAILED
            self._disarm("command")
            return MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return MAV_RESULT_FAILED
            return self._set_mode(MODE_NAMES.get(int(p[1]), ""), now, "DO_SET_MODE")
        if cmd == mav2.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(float(p[6]), now)
        if cmd == mav2.MAV_CMD_NAV_LAND:
            return self._set_mode("LAND", now, "NAV_LAND")
        if cmd == mav2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode("RTL", now, "NAV_RETURN_TO_LAUNCH")
        if cmd == mav2.MAV_CMD_CONDITION_YAW:
            return self._condition_yaw(p)
        if cmd == mav2.MAV_CMD_BATTERY_RESET:
            # AP_BattMonitor::reset_remaining_mask: the remaining charge set, the failsafe cleared
            self._battery = max(0.0, min(100.0, float(p[1])))
            self._batt_failsafe, self._batt_action, self._batt_low_since = 0, 0, None
            return MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(int(p[0]), p[1])
        if cmd == mav2.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(int(p[0]), now)
        if cmd == mav2.MAV_CMD_GET_HOME_POSITION:
            return self._request_message(mav2.MAVLINK_MSG_ID_HOME_POSITION, now)
        if cmd == mav2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return self._request_message(mav2.MAVLINK_MSG_ID_AUTOPILOT_VERSION, now)
        return MAV_RESULT_UNSUPPORTED

    def _condition_yaw(self, p: tuple[float, ...]) -> int:
        if self._mode != "GUIDED" or not self._armed or self._on_ground:
            return MAV_RESULT_FAILED
        angle, direction, relative = p[0], p[2], p[3]
        if relative:
            self._target_yaw = self._yaw + (angle if direction >= 0 else -angle)
        else:
            delta = (angle - self._yaw + 180.0) % 360.0 - 180.0
            self._target_yaw = self._yaw + delta
        self._target_yaw_rate = 0.0
        return MAV_RESULT_ACCEPTED

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        name = _MSG_NAMES.get(msg_id)
        if name is None or name not in self._rates:
            return MAV_RESULT_FAILED
        if interval_us < 0:
            rate = 0.0
        elif interval_us == 0:
            rate = self._default_rates[name]
        else:
            rate = 1e6 / interval_us
        self._rates[name] = rate
        self._next_send.pop(name, None)
        return MAV_RESULT_ACCEPTED

    def _request_message(self, msg_id: int, now: float) -> int:
        name = _MSG_NAMES.get(msg_id)
        if name is None or (name not in self._rates and name != "AUTOPILOT_VERSION"):
            return MAV_RESULT_UNSUPPORTED
        if name == "HOME_POSITION" and self._home is None:
            return MAV_RESULT_FAILED
        msg = self._make(name, now)
        if msg is None:
            return MAV_RESULT_DENIED
        self._after_ack.append(msg)
        return MAV_RESULT_ACCEPTED

    def _on_request_data_stream(self, msg: Any, now: float) -> None:
        if not self._for_me(msg):
            return
        if msg.req_stream_id == mav2.MAV_DATA_STREAM_ALL:
            names: Iterable[str] = [n for group in DATA_STREAMS.values() for n in group]
        else:
            names = DATA_STREAMS.get(msg.req_stream_id, ())
        rate = float(msg.req_message_rate) if msg.start_stop else 0.0
        for name in names:
            self._rates[name] = rate
            self._next_send.pop(name, None)

    def _on_position_target(self, msg: Any, now: float) -> None:
        if not self._for_me(msg, with_component=False):
            return
        if self._mode != "GUIDED" or not self._armed or (self._on_ground and self._takeoff_alt is None):
            return  # ArduCopter ignores targets outside GUIDED or before takeoff
        mask = msg.type_mask
        body = msg.coordinate_frame in (mav2.MAV_FRAME_BODY_NED, mav2.MAV_FRAME_BODY_OFFSET_NED)
        offset = msg.coordinate_frame in (mav2.MAV_FRAME_LOCAL_OFFSET_NED,) or body
        if msg.coordinate_frame not in (
            mav2.MAV_FRAME_LOCAL_NED,
            mav2.MAV_FRAME_LOCAL_OFFSET_NED,
            mav2.MAV_FRAME_BODY_NED,
            mav2.MAV_FRAME_BODY_OFFSET_NED,
        ):
            return
        psi = math.radians(self._yaw)

        def rotate(x: float, y: float) -> tuple[float, float]:
            if not body:
                return x, y
            return x * math.cos(psi) - y * math.sin(psi), x * math.sin(psi) + y * math.cos(psi)

        use_pos = not mask & _TM_POS
        use_vel = not mask & _TM_VEL
        if not (use_pos or use_vel):
            return
        if use_pos:
            dn, de = rotate(msg.x, msg.y)
            base = (self._n, self._e, self._d) if offset else (0.0, 0.0, 0.0)
            self._target_pos = (base[0] + dn, base[1] + de, base[2] + msg.z)
            self._guided = "position"
        else:
            self._target_pos = None
            self._guided = "velocity"
        vn, ve = rotate(msg.vx, msg.vy) if use_vel else (0.0, 0.0)
        self._target_vel = (vn, ve, msg.vz if use_vel else 0.0)
        if not mask & mav2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE:
            self._target_yaw_rate = math.degrees(msg.yaw_rate)
            self._target_yaw = None
        elif not mask & mav2.POSITION_TARGET_TYPEMASK_YAW_IGNORE:
            target = math.degrees(msg.yaw) + (self._yaw if body else 0.0)
            self._target_yaw = self._yaw + (target - self._yaw + 180.0) % 360.0 - 180.0
            self._target_yaw_rate = 0.0
        else:
            self._target_yaw, self._target_yaw_rate = None, 0.0
        self._takeoff_alt = None  # a new target ends a guided takeoff, as in ArduCopter
        self._last_target = now

    def _on_heartbeat(self, msg: Any, now: float) -> None:
        # GCS_MAVLINK::handle_heartbeat: only the GCS id's heartbeats feed the GCS failsafe
        if msg.get_srcSystem() == round(self._params[self.gcs_sysid_param]):
            self._gcs_seen = now

    def _param_value(self, name: str) -> Any:
        names = list(self._params)
        return self._encoder.param_value_encode(
            name.encode(), self._params[name], self._param_types[name], len(names), names.index(name)
        )

    @staticmethod
    def _param_name(raw: Any) -> str:
        text = raw if isinstance(raw, str) else bytes(raw).decode("ascii", "replace")
        return text.rstrip("\x00")

    def _on_param_request_read(self, msg: Any, now: float) -> None:
        if not self._for_me(msg):
            return
        names = list(self._params)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._outbox.append(self._param_value(names[msg.param_index]))
            return
        name = self._param_name(msg.param_id)
        if name in self._params:  # ArduPilot does not answer for a parameter it does not have
            self._outbox.append(self._param_value(name))

    def _on_param_request_list(self, msg: Any, now: float) -> None:
        if self._for_me(msg):
            self._outbox.extend(self._param_value(name) for name in self._params)

    def _on_param_set(self, msg: Any, now: float) -> None:
        if not self._for_me(msg):
            return
        name = self._param_name(msg.param_id)
        if name not in self._params or not math.isfinite(msg.param_value):
            return
        value = float(msg.param_value)
        if self._param_types[name] != _R32:
            value = float(round(value))
        LOG.info("parameter %s = %g (PARAM_SET from %d)", name, value, msg.get_srcSystem())
        self._apply_param(name, value, now)
        self._outbox.append(self._param_value(name))

    def _apply_param(self, name: str, value: float, now: float) -> None:
        self._params[name] = value
        if name == "SIM_BATT_VOLTAGE":
            self._voltage_override = value
        elif name == "SIM_GPS_DISABLE":
            off = round(value) != 0
            if off and self._gps_off_since is None:
                self._gps_off_since = now
            elif not off:
                self._gps_off_since = None

    _HANDLERS: dict[str, Callable[[MavlinkVehicle, Any, float], None]] = {
        "HEARTBEAT": _on_heartbeat,
        "PARAM_REQUEST_READ": _on_param_request_read,
        "PARAM_REQUEST_LIST": _on_param_request_list,
        "PARAM_SET": _on_param_set,
        "SET_MODE": _on_set_mode,
        "COMMAND_LONG": _on_command,
        "COMMAND_INT": _on_command,
        "REQUEST_DATA_STREAM": _on_request_data_stream,
        "SET_POSITION_TARGET_LOCAL_NED": _on_position_target,
    }

    # -- physics (I/O thread, lock held) -------------------------------------------------------------

    def _step(self, dt: float, now: float) -> None:
        if not self._booted and now - self._t0 >= self.boot_delay:
            self._booted = True
            if self._mode != self.initial_mode:
                LOG.info("boot done: mode %s reverted to %s", self._mode, self.initial_mode)
                self._mode = self.initial_mode  # silently, as ArduCopter's init does
                self._rtl_phase = None
            self._text("ArduCopter V4.5.7 (emulator)")
        if not self._ekf_announced and self._position_ok(now):
            self._ekf_announced = True
            self._text("EKF3 IMU0 is using GPS")
            if self._home is None:
                self._set_home_here()
        if self._armed:
            self._battery = max(0.0, self._battery - self.battery_drain * dt)
        self._failsafes(now)
        target_vel, yaw_rate = self._control(now)
        alpha = 1.0 - math.exp(-dt / self.velocity_tau) if self.velocity_tau > 0 else 1.0
        self._vn += (target_vel[0] - self._vn) * alpha
        self._ve += (target_vel[1] - self._ve) * alpha
        self._vd += (target_vel[2] - self._vd) * alpha
        self._n += self._vn * dt
        self._e += self._ve * dt
        self._d += self._vd * dt
        if self._target_yaw is not None and abs(self._target_yaw - self._yaw) <= abs(yaw_rate) * dt:
            self._yaw, self._target_yaw, yaw_rate = self._target_yaw, None, 0.0
        else:
            self._yaw += yaw_rate * dt
        self._yaw_rate = yaw_rate
        self._ground_contact(now)

    # -- failsafes (I/O thread, lock held) ----------------------------------------------------------

    def _failsafe_mode(self, failsafe: str, mode: str, now: float) -> None:
        """events.cpp do_failsafe_action: set_mode_RTL_or_land_with_pause for RTL (LAND if RTL is refused),
        set_mode_land_with_pause for LAND (mode_land.cpp: a LAND_WITH_DELAY hover before descending).
        Copter::set_mode to the mode it is already in changes nothing (no restart, no pause)."""
        if self._mode == mode:
            return
        if self._set_mode(mode, now, source=failsafe) != MAV_RESULT_ACCEPTED:
            self._set_mode("LAND", now, source=failsafe)
        if self._mode == "LAND":
            self._land_pause_until = now + LAND_WITH_DELAY
        self.failsafe_modes.append((failsafe, self._mode))

    def _fs_option(self, bit: int) -> bool:
        return bool(round(self._params["FS_OPTIONS"]) & bit)

    def _battery_land_priority(self) -> bool:
        """AP_BattMonitor has failsafed with LAND or TERMINATE (priority <= FAILSAFE_LAND_PRIORITY)."""
        return self._batt_failsafe > 0 and self._batt_action in (1, 5)

    def _failsafes(self, now: float) -> None:
        self._gcs_check(now)
        self._rc_check(now)
        self._fence_check(now)
        self._battery_check(now)
        self._ekf_check(now)

    def _gcs_check(self, now: float) -> None:
        """events.cpp failsafe_gcs_check / failsafe_gcs_on_event (Copter-4.6.3)."""
        action = round(self._params["FS_GCS_ENABLE"])
        if action == 0 or self._gcs_seen == 0.0:
            return
        lost = now - self._gcs_seen > self._params["FS_GCS_TIMEOUT"]
        if lost and not self._gcs_failsafe:
            self._gcs_failsafe = True
            mode = _FS_GCS_MODES.get(action, "RTL")
            if not self._armed:
                self._text("GCS Failsafe", mav2.MAV_SEVERITY_WARNING)
                return
            if self._land_complete():
                self._text("GCS Failsafe - Disarming", mav2.MAV_SEVERITY_WARNING)
                self._disarm("GCS failsafe")
                return
            if self._landing() and self._battery_land_priority():
                self._text("GCS + Battery Failsafe - Continuing Landing", mav2.MAV_SEVERITY_WARNING)
                mode = "LAND"
            elif self._landing() and self._fs_option(FS_OPT_CONTINUE_IF_LANDING):
                self._text("GCS Failsafe - Continuing Landing", mav2.MAV_SEVERITY_WARNING)
                mode = "LAND"
            elif self._fs_option(FS_OPT_GCS_CONTINUE_IF_PILOT_CONTROL) and self._mode not in AUTOPILOT_MODES:
                self._text("GCS Failsafe - Continuing Pilot Control", mav2.MAV_SEVERITY_WARNING)
                return
            else:
                self._text("GCS Failsafe", mav2.MAV_SEVERITY_WARNING)
            self._failsafe_mode("GCS failsafe", mode, now)
        elif not lost and self._gcs_failsafe:
            self._gcs_failsafe = False
            self._text("GCS Failsafe Cleared", mav2.MAV_SEVERITY_WARNING)

    def _rc_check(self, now: float) -> None:
        """radio.cpp (no pulses with SIM_RC_FAIL 1) and events.cpp failsafe_radio_on_event / _off_event."""
        lost = round(self._params["SIM_RC_FAIL"]) == 1
        if lost == self._rc_failsafe:
            return
        self._rc_failsafe = lost
        if not lost:
            self._text("Radio Failsafe Cleared", mav2.MAV_SEVERITY_WARNING)
            return
        action = round(self._params["FS_THR_ENABLE"])
        mode = _FS_THR_MODES.get(action, "LAND") if action else ""
        if self._land_complete():
            self._text("Radio Failsafe - Disarming", mav2.MAV_SEVERITY_WARNING)
            self._disarm("radio failsafe")
            return
        if self._landing() and self._battery_land_priority():
            self._text("Radio + Battery Failsafe - Continuing Landing", mav2.MAV_SEVERITY_WARNING)
            mode = "LAND"
        elif self._landing() and self._fs_option(FS_OPT_CONTINUE_IF_LANDING):
            self._text("Radio Failsafe - Continuing Landing", mav2.MAV_SEVERITY_WARNING)
            mode = "LAND"
        elif (
            self._mode == "GUIDED"
            and self._fs_option(FS_OPT_RC_CONTINUE_IF_GUIDED)
            and round(self._params["FS_GCS_ENABLE"])
        ):
            self._text("Radio Failsafe - Continuing Guided Mode", mav2.MAV_SEVERITY_WARNING)
            return
        else:
            self._text("Radio Failsafe", mav2.MAV_SEVERITY_WARNING)
        if mode and self._armed:
            self._failsafe_mode("RC failsafe", mode, now)

    def _fence_check(self, now: float) -> None:
        if not round(self._params["FENCE_ENABLE"]) or not self._armed:
            self._fence_breached = False
            return
        hn, he = self._home_ned()
        outside = math.hypot(self._n - hn, self._e - he) > self._params["FENCE_RADIUS"]
        too_high = -self._d > self._params["FENCE_ALT_MAX"]
        breached = outside or too_high
        if breached and not self._fence_breached:
            self._fence_breaches += 1
            self._fence_breach_type = mav2.FENCE_BREACH_BOUNDARY if outside else mav2.FENCE_BREACH_MAXALT
            self._fence_breach_time = int((now - self._t0) * 1000)
            # AC_Fence (Copter-4.6.3 SITL says "Circle fence breached", NOTICE)
            self._text(f"{'Circle' if outside else 'Max Alt'} fence breached", mav2.MAV_SEVERITY_NOTICE)
            action = round(self._params["FENCE_ACTION"])
            if action in _FENCE_MODES:
                self._failsafe_mode("fence breach", _FENCE_MODES[action], now)
        elif self._fence_breached and not breached:
            self._text("Fence breach cleared", mav2.MAV_SEVERITY_NOTICE)
        self._fence_breached = breached

    def _voltage(self) -> float:
        if self._voltage_override is not None:
            return self._voltage_override
        return self.battery_cells * (3.2 + 0.01 * self._battery)  # 4.2 V a cell full, 3.2 V empty

    def _battery_check(self, now: float) -> None:
        if not round(self._params["BATT_MONITOR"]):
            return
        volts = self._voltage()
        critical = self._params["BATT_CRT_VOLT"] > 0 and volts < self._params["BATT_CRT_VOLT"]
        low = self._params["BATT_LOW_VOLT"] > 0 and volts < self._params["BATT_LOW_VOLT"]
        if not (low or critical):
            self._batt_low_since = None
            return
        if self._batt_low_since is None:
            self._batt_low_since = now
        if now - self._batt_low_since < self._params["BATT_LOW_TIMER"]:
            return
        level = 2 if critical else 1
        if level <= self._batt_failsafe:
            return  # AP_BattMonitor latches the worst failsafe seen (until MAV_CMD_BATTERY_RESET)
        self._batt_failsafe = level
        word = "critical" if level == 2 else "low"
        self._text(f"Battery 1 is {word} {volts:.2f}V used 0 mAh", mav2.MAV_SEVERITY_WARNING)
        action = round(self._params["BATT_FS_CRT_ACT" if level == 2 else "BATT_FS_LOW_ACT"])
        self._batt_action = action
        # events.cpp handle_battery_failsafe (Copter-4.6.3)
        if self._land_complete():
            self._text("Battery Failsafe - Disarming", mav2.MAV_SEVERITY_WARNING)
            self._disarm("battery failsafe")
            return
        if self._landing() and self._fs_option(FS_OPT_CONTINUE_IF_LANDING) and action != 0:
            self._text("Battery Failsafe - Continuing Landing", mav2.MAV_SEVERITY_WARNING)
            action = 1
        else:
            self._text("Battery Failsafe", mav2.MAV_SEVERITY_WARNING)
        if not self._armed or action == 0:
            return
        if action == 5:
            self._disarm("battery failsafe: terminate")
        elif action in _BATT_MODES:
            self._failsafe_mode("battery failsafe", _BATT_MODES[action], now)

    def _ekf_bad_from(self, now: float) -> float | None:
        """Since when the EKF's variances are over FS_EKF_THRESH (fail_ekf, or the GPS off too long)."""
        if self._ekf_bad_since is not None:
            return self._ekf_bad_since
        if self._gps_off_since is not None and self._gps_lost(now):
            return self._gps_off_since + GPS_DEAD_RECKONING
        return None

    def _ekf_bad(self, now: float) -> bool:
        return self._ekf_bad_from(now) is not None

    def _ekf_check(self, now: float) -> None:
        """ekf_check.cpp (Copter-4.6.3): 1 s of bad variances -> "EKF variance" and FS_EKF_ACTION
        (failsafe_ekf_event: set_mode_land_with_pause, ALT_HOLD for 2); good again -> "EKF Failsafe
        Cleared" (failsafe_ekf_off_event)."""
        since = self._ekf_bad_from(now)
        if since is None:
            if self._ekf_failsafe:
                self._ekf_failsafe = False
                self._text("EKF Failsafe Cleared", mav2.MAV_SEVERITY_CRITICAL)
            return
        if self._ekf_failsafe or now - since < _EKF_BAD_FOR:
            return
        self._ekf_failsafe = True
        self._text("EKF variance", mav2.MAV_SEVERITY_CRITICAL)
        action = round(self._params["FS_EKF_ACTION"])
        if not self._armed or action == 0:
            return
        needs_position = self._mode in POSITION_MODES
        if action == 3 or (action == 1 and needs_position):
            self._failsafe_mode("EKF failsafe", "LAND", now)
            self._text("EKF Failsafe: changed to LAND Mode", mav2.MAV_SEVERITY_CRITICAL)
        elif action == 2 and needs_position:
            self._failsafe_mode("EKF failsafe", "ALT_HOLD", now)

    def _control(self, now: float) -> tuple[tuple[float, float, float], float]:
        """The velocity (NED, m/s) and yaw rate (deg/s) the flight controller asks for now."""
        if not self._armed or (self._on_ground and self._takeoff_alt is None):
            return (0.0, 0.0, 0.0), 0.0
        alt = -self._d
        yaw_rate = 0.0
        vel = (0.0, 0.0, 0.0)
        if self._mode == "GUIDED":
            if self._takeoff_alt is not None:
                self._guided = "takeoff"
                vel = (0.0, 0.0, -min(self.climb_rate, 2.5 * (self._takeoff_alt - alt) + 0.3))
                if alt >= self._takeoff_alt - 0.1:
                    self._takeoff_alt = None
                    self._guided = "hover"
            elif self._guided in ("velocity", "position"):
                if now - self._last_target > self._params["GUID_TIMEOUT"]:
                    self._guided = "hover"  # ArduCopter's guided timeout: stop
                    self._target_yaw_rate, self._target_yaw = 0.0, None
                elif self._guided == "position" and self._target_pos is not None:
                    tn, te, td = self._target_pos
                    vel = (1.0 * (tn - self._n), 1.0 * (te - self._e), 1.0 * (td - self._d))
                else:
                    vel = self._target_vel
            yaw_rate = self._yaw_control()
        elif self._mode == "RTL":
            vel = self._rtl(alt, now)
        elif self._mode == "LAND" and now >= self._land_pause_until:
            vel = (0.0, 0.0, self._land_rate(alt))
        return self._limit(vel), yaw_rate

    def _yaw_control(self) -> float:
        if self._target_yaw is not None:
            err = self._target_yaw - self._yaw
            rate = math.copysign(max(abs(4.0 * err), 30.0), err)  # slows down near the target, then snaps
            return max(-self.yaw_rate_max, min(self.yaw_rate_max, rate))
        return max(-self.yaw_rate_max, min(self.yaw_rate_max, self._target_yaw_rate))

    def _rtl(self, alt: float, now: float) -> tuple[float, float, float]:
        """mode_rtl.cpp (Copter-4.6.3): climb straight up to the return altitude, fly home at it, loiter
        RTL_LOIT_TIME over home, then land (RTL_ALT_FINAL 0)."""
        hn, he = self._home_ned()
        if self._rtl_phase == "climb":
            if alt < self._rtl_alt - 0.1:
                return (0.0, 0.0, -min(self.max_climb_rate, 2.5 * (self._rtl_alt - alt) + 0.3))
            self._rtl_phase = "return"
        if self._rtl_phase == "return":
            dn, de = hn - self._n, he - self._e
            dist = math.hypot(dn, de)
            if dist > 0.3:
                speed = min(self.rtl_speed, 2.5 * dist)
                return (dn / dist * speed, de / dist * speed, 0.0)
            self._rtl_phase = "loiter"
            self._rtl_loiter_end = now + self._params["RTL_LOIT_TIME"] / 1000.0
        # over home it holds the position (loiter, then the landing's position controller)
        hold = (max(-2.0, min(2.0, hn - self._n)), max(-2.0, min(2.0, he - self._e)))
        if self._rtl_phase == "loiter":
            if now < self._rtl_loiter_end:
                return (hold[0], hold[1], 0.0)
            self._rtl_phase = "land"
        return (hold[0], hold[1], self._land_rate(alt))

    def _land_rate(self, alt: float) -> float:
        """mode_land.cpp: LAND_SPEED below LAND_ALT_LOW, the faster descent (WPNAV_SPEED_DN) above it."""
        return self.land_speed_high if alt > self.land_alt_low else self._params["LAND_SPEED"] / 100.0

    def _limit(self, vel: tuple[float, float, float]) -> tuple[float, float, float]:
        vn, ve, vd = vel
        h = math.hypot(vn, ve)
        if h > self.max_speed:
            vn, ve = vn / h * self.max_speed, ve / h * self.max_speed
        vd = max(-self.max_climb_rate, min(self.max_descent_rate, vd))
        return vn, ve, vd

    def _ground_contact(self, now: float) -> None:
        if self._d >= 0.0 and self._vd >= 0.0:
            if not self._on_ground:
                self._on_ground = True
                self._ground_since = now
            self._d = 0.0
            self._vn = self._ve = self._vd = 0.0
        elif self._d < -0.05:
            self._on_ground = False
        if not (self._armed and self._on_ground and self._takeoff_alt is None):
            return
        if self._mode in ("LAND", "RTL") and now - self._ground_since >= self.land_detect_time:
            self._disarm("landed")
        elif now - self._ground_since >= self.disarm_delay:
            self._disarm("auto-disarm")

    # -- outgoing messages ---------------------------------------------------------------------------

    def _make(self, name: str, now: float) -> Any | None:
        """Encode one telemetry message from the current state (lock held)."""
        enc = self._encoder
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        pos_ok = self._position_ok(now)
        # without GPS the AHRS still reports its last (dead-reckoned) position, as 4.6.3 SITL does
        lat, lon = self._latlon() if pos_ok or self._gps_off_since is not None else (0.0, 0.0)
        alt = -self._d
        home_alt = self._home[2] if self._home else self.origin[2]
        yaw_rad = math.radians(((self._yaw + 180.0) % 360.0) - 180.0)
        if name == "HEARTBEAT":
            base = mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav2.MAV_MODE_FLAG_STABILIZE_ENABLED
            base |= mav2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            if self._mode in POSITION_MODES or self._mode == "LAND":
                base |= mav2.MAV_MODE_FLAG_GUIDED_ENABLED
            if self._armed:
                base |= mav2.MAV_MODE_FLAG_SAFETY_ARMED
            return enc.heartbeat_encode(
                mav2.MAV_TYPE_QUADROTOR,
                mav2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                base,
                COPTER_MODES[self._mode],
                self._system_status(now),
                3,
            )
        if name == "GLOBAL_POSITION_INT":
            return enc.global_position_int_encode(
                boot_ms,
                round(lat * 1e7),
                round(lon * 1e7),
                round((self.origin[2] + alt) * 1000),
                round((self.origin[2] + alt - home_alt) * 1000),
                round(self._vn * 100),
                round(self._ve * 100),
                round(self._vd * 100),
                round(self._yaw % 360.0 * 100) % 36000,
            )
        if name == "ATTITUDE":
            fwd = self._vn * math.cos(yaw_rad) + self._ve * math.sin(yaw_rad)
            right = -self._vn * math.sin(yaw_rad) + self._ve * math.cos(yaw_rad)
            return enc.attitude_encode(
                boot_ms,
                math.radians(2.0 * right),
                math.radians(-2.0 * fwd),
                yaw_rad,
                0.0,
                0.0,
                math.radians(self._yaw_rate),
            )
        if name == "SYS_STATUS":
            # GCS_MAVLINK::update_sensor_status_flags: a sensor is present/enabled, and healthy or not
            present = _SENSORS | mav2.MAV_SYS_STATUS_PREARM_CHECK | mav2.MAV_SYS_STATUS_AHRS
            present |= mav2.MAV_SYS_STATUS_SENSOR_RC_RECEIVER  # SITL's RC input, seen since boot
            if round(self._params["BATT_MONITOR"]):
                present |= mav2.MAV_SYS_STATUS_SENSOR_BATTERY
            if round(self._params["FENCE_ENABLE"]):
                present |= mav2.MAV_SYS_STATUS_GEOFENCE
            health = present if self._gps_fix(now) else present & ~mav2.MAV_SYS_STATUS_SENSOR_GPS
            if not pos_ok or self.refuse_arm:
                health &= ~mav2.MAV_SYS_STATUS_PREARM_CHECK
            if self._batt_failsafe:
                health &= ~mav2.MAV_SYS_STATUS_SENSOR_BATTERY
            if self._fence_breached:
                health &= ~mav2.MAV_SYS_STATUS_GEOFENCE
            if self._ekf_bad(now):
                health &= ~mav2.MAV_SYS_STATUS_AHRS
            if self._rc_failsafe:
                health &= ~mav2.MAV_SYS_STATUS_SENSOR_RC_RECEIVER
            current = 1500 if self._armed else 50  # cA
            remaining = round(self._battery) if self.report_remaining else -1
            return enc.sys_status_encode(
                present,
                present,
                health,
                150,
                round(self._voltage() * 1000),
                current,
                remaining,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        if name == "BATTERY_STATUS":
            volts = self._voltage()
            if self.per_cell_monitor:
                cells = [round(volts / self.battery_cells * 1000)] * self.battery_cells
            else:
                cells = [min(round(volts * 1000), 65534)]  # ArduPilot's analog monitors: the pack in cell 1
            voltages = (cells + [65535] * 10)[:10]
            charge = {
                0: mav2.MAV_BATTERY_CHARGE_STATE_OK,
                1: mav2.MAV_BATTERY_CHARGE_STATE_LOW,
                2: mav2.MAV_BATTERY_CHARGE_STATE_CRITICAL,
            }[self._batt_failsafe]
            remaining = round(self._battery) if self.report_remaining else -1
            return enc.battery_status_encode(
                0,
                mav2.MAV_BATTERY_FUNCTION_UNKNOWN,
                mav2.MAV_BATTERY_TYPE_LIPO,
                32767,
                voltages,
                1500 if self._armed else 50,
                -1,
                -1,
                remaining,
                0,
                charge,
                [0, 0, 0, 0],
            )
        if name == "FENCE_STATUS":
            if not round(self._params["FENCE_ENABLE"]):
                return None  # ArduPilot sends it only with the fence enabled
            return enc.fence_status_encode(
                1 if self._fence_breached else 0,
                self._fence_breaches,
                self._fence_breach_type,
                self._fence_breach_time,
            )
        if name == "EXTENDED_SYS_STATE":
            return enc.extended_sys_state_encode(mav2.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if name == "GPS_RAW_INT":
            if self._gps_fix(now):
                glat, glon = self._latlon()
                return enc.gps_raw_int_encode(
                    int((now - self._t0) * 1e6),
                    mav2.GPS_FIX_TYPE_3D_FIX,
                    round(glat * 1e7),
                    round(glon * 1e7),
                    round((self.origin[2] + alt) * 1000),
                    70,
                    120,
                    round(math.hypot(self._vn, self._ve) * 100),
                    round(math.degrees(math.atan2(self._ve, self._vn)) % 360.0 * 100) % 36000,
                    12,
                )
            return enc.gps_raw_int_encode(
                int((now - self._t0) * 1e6), mav2.GPS_FIX_TYPE_NO_GPS, 0, 0, 0, 65535, 65535, 0, 65535, 0
            )
        if name == "EKF_STATUS_REPORT":
            if self._ekf_bad(now):
                good = _EKF_GOOD if self._ekf_bad_since is not None else _EKF_NO_POSITION
                return enc.ekf_status_report_encode(good, 1.2, 1.3, 0.9, 0.5, 0.0)
            if not self._booted:
                return enc.ekf_status_report_encode(mav2.EKF_UNINITIALIZED, 1.0, 1.0, 1.0, 1.0, 0.0)
            if pos_ok:
                return enc.ekf_status_report_encode(_EKF_GOOD, 0.02, 0.03, 0.02, 0.05, 0.0)
            return enc.ekf_status_report_encode(_EKF_NO_POSITION, 0.1, 1.0, 0.1, 0.1, 0.0)
        if name == "VFR_HUD":
            speed = math.hypot(self._vn, self._ve)
            return enc.vfr_hud_encode(
                speed,
                speed,
                round(self._yaw % 360.0) % 360,
                40 if self._armed and not self._on_ground else 0,
                self.origin[2] + alt,
                -self._vd,
            )
        if name == "LOCAL_POSITION_NED":
            return enc.local_position_ned_encode(
                boot_ms, self._n, self._e, self._d, self._vn, self._ve, self._vd
            )
        if name == "HOME_POSITION":
            hlat, hlon, halt = self._home or (self.origin[0], self.origin[1], self.origin[2])
            hn, he = self._home_ned()
            return enc.home_position_encode(
                round(hlat * 1e7),
                round(hlon * 1e7),
                round(halt * 1000),
                hn,
                he,
                -(halt - self.origin[2]),
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                int((now - self._t0) * 1e6),
            )
        if name == "SYSTEM_TIME":
            return enc.system_time_encode(int(time.time() * 1e6), boot_ms)
        if name == "AUTOPILOT_VERSION":
            caps = (
                mav2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mav2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mav2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mav2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
            )
            version = (4 << 24) | (5 << 16) | (7 << 8) | mav2.FIRMWARE_VERSION_TYPE_OFFICIAL
            return enc.autopilot_version_encode(caps, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0)
        raise KeyError(name)

    def _due_messages(self, now: float) -> None:
        for name, rate in self._rates.items():
            if rate <= 0:
                continue
            due = self._next_send.get(name, now)
            if now >= due:
                msg = self._make(name, now)
                if msg is not None:
                    self._outbox.append(msg)
                # keep the cadence without bursts after a stall
                self._next_send[name] = max(due + 1.0 / rate, now)

    def _flush(self) -> None:
        with self._lock:
            outbox, self._outbox = self._outbox, []
            link_up = self._link_up
            for msg in outbox:
                self._encoder.send(msg)
            wire = self._wire.take() + self._injected
            self._injected = []
            if self._cut:
                self._held_out.extend(wire)  # the link keeps it: delivered when restored
                return
            if self._release:
                wire, self._held_out = self._held_out + wire, []
        if not link_up or not wire:
            return
        data = b"".join(wire)
        if self._udp is not None:
            for addr in list(self._udp_peers):
                for frame in wire:  # one datagram per message, like ArduPilot
                    try:
                        self._udp.sendto(frame, addr)
                    except OSError as exc:
                        LOG.debug("udp send to %s failed: %s", addr, exc)
                        break
        for peer in list(self._tcp_peers):
            assert peer.sock is not None
            try:
                peer.sock.sendall(data)
            except OSError:
                self._drop_tcp(peer)
        for peer in list(self._memory_peers):
            assert peer.link is not None
            if peer.link.closed:
                self._drop_memory(peer)
            else:
                peer.link.feed(data)

    # -- the I/O thread ------------------------------------------------------------------------------

    def _run(self) -> None:
        tick = 1.0 / self.tick_rate
        last = time.monotonic()
        next_tick = last
        while not self._workers.stop.is_set():
            socks = [s for s in (self._udp, self._tcp) if s is not None]
            socks += [p.sock for p in self._tcp_peers if p.sock is not None]
            try:
                ready, _, _ = select.select(socks, [], [], max(0.0, min(next_tick - time.monotonic(), 0.05)))
            except (OSError, ValueError):
                ready = []
                self._tcp_peers = [p for p in self._tcp_peers if p.sock is not None and p.sock.fileno() >= 0]
            for sock in ready:
                self._read(sock)
            while self._memory_in:
                peer, data = self._memory_in.popleft()
                self._receive(peer, data, time.monotonic())
            self._release_backlog()
            now = time.monotonic()
            if now >= next_tick:
                with self._lock:
                    self._step(max(now - last, 0.0), now)
                    self._due_messages(now)
                last = now
                next_tick = now + tick
            self._flush()

    def _read(self, sock: socket.socket) -> None:
        now = time.monotonic()
        if sock is self._tcp:
            try:
                conn, _addr = sock.accept()
            except OSError:
                return
            conn.settimeout(1.0)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._tcp_peers.append(self._peer(sock=conn))
            return
        if sock is self._udp:
            try:
                data, addr = sock.recvfrom(65535)
            except OSError:
                return
            peer = self._udp_peers.get(addr)
            if peer is None:
                if len(self._udp_peers) >= 16:
                    return
                peer = self._udp_peers[addr] = self._peer(addr=addr)
        else:
            peer = next((p for p in self._tcp_peers if p.sock is sock), None)
            if peer is None:
                return
            try:
                data = sock.recv(65535)
            except OSError:
                data = b""
            if not data:
                self._drop_tcp(peer)
                return
        self._receive(peer, data, now)

    def _receive(self, peer: _Peer, data: bytes, now: float) -> None:
        """Bytes from `peer` reach the autopilot: unless the link is down, or cut (then they wait)."""
        with self._lock:
            if not self._link_up or self._uplink_down:
                return
            if self._cut:
                self._held_in.append((peer, data))  # in the link's buffer, not yet at the autopilot
                return
            for msg in peer.parse(data):
                self._handle(msg, now)

    def _release_backlog(self) -> None:
        """The cut ended: what the link kept reaches the autopilot now, all at once (a TCP flush)."""
        with self._lock:
            if not self._release:
                return
            held, self._held_in = self._held_in, []
            now = time.monotonic()
            for peer, data in held:
                for msg in peer.parse(data):
                    self._handle(msg, now)
        self._flush()  # sends the held output, then clears the flag
        with self._lock:
            self._release = False

    def _drop_tcp(self, peer: _Peer) -> None:
        if peer in self._tcp_peers:
            self._tcp_peers.remove(peer)
            self._signing_rejected_gone += peer.rejected
        if peer.sock is not None:
            peer.sock.close()

    def _drop_memory(self, peer: _Peer) -> None:
        with self._lock:
            if peer in self._memory_peers:
                self._memory_peers.remove(peer)
                self._signing_rejected_gone += peer.rejected

    def _close_transports(self) -> None:
        for peer in list(self._tcp_peers):
            self._drop_tcp(peer)
        for sock in (self._udp, self._tcp):
            if sock is not None:
                sock.close()
        self._udp = self._tcp = None


_MSG_NAMES: dict[int, str] = {
    getattr(mav2, f"MAVLINK_MSG_ID_{name}"): name
    for name in ("HEARTBEAT", "AUTOPILOT_VERSION", *DEFAULT_RATES)
}


def main(argv: list[str] | None = None) -> int:
    """Run a vehicle until SIGTERM/SIGINT (for tests that need it in another process or namespace)."""
    parser = argparse.ArgumentParser(
        prog="python -m tests.emulators.mavlink_vehicle", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--udp-port", type=int, default=0, help="-1 disables UDP")
    parser.add_argument("--tcp-port", type=int, default=-1, help="-1 disables TCP, 0 picks a free port")
    parser.add_argument("--udp-target", default=None, help="HOST:PORT to push to (like SITL's udpclient)")
    parser.add_argument("--home", default=None, help="LAT,LON[,ALT]")
    parser.add_argument("--sysid", type=int, default=1, help="MAVLink system id (SYSID_THISMAV)")
    parser.add_argument(
        "--profile",
        choices=("default", "arducopter"),
        default="default",
        help="arducopter: ArduCopter 4.6.3's speeds and parameter defaults (ARDUCOPTER)",
    )
    parser.add_argument("--boot-delay", type=float, default=None)
    parser.add_argument("--ekf-delay", type=float, default=None)
    parser.add_argument("--gps-delay", type=float, default=None)
    parser.add_argument("--battery", type=float, default=100.0)
    parser.add_argument("--refuse-arm", action="store_true")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="an ArduCopter parameter (FS_GCS_ENABLE=1, SYSID_MYGCS=245, ...); repeatable",
    )
    parser.add_argument("--signing-key", default=None, help="MAVLink 2 signing key, 64 hex digits")
    parser.add_argument("--log-level", default="WARNING")
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(name)s %(message)s")

    kwargs: dict[str, Any] = dict(ARDUCOPTER) if args.profile == "arducopter" else {}
    for name in ("boot_delay", "ekf_delay", "gps_delay"):
        if getattr(args, name) is not None:
            kwargs[name] = getattr(args, name)
    if args.home:
        parts = [float(v) for v in args.home.split(",")]
        kwargs.update(home_lat=parts[0], home_lon=parts[1])
        if len(parts) > 2:
            kwargs["home_alt"] = parts[2]
    if args.param:
        kwargs["params"] = {k: float(v) for k, _, v in (item.partition("=") for item in args.param)}
    if args.signing_key:
        kwargs["signing_key"] = bytes.fromhex(args.signing_key)
    if args.udp_target:
        host, _, port = args.udp_target.rpartition(":")
        kwargs["udp_target"] = (host, int(port))
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    vehicle = MavlinkVehicle(
        args.host,
        None if args.udp_port < 0 else args.udp_port,
        None if args.tcp_port < 0 else args.tcp_port,
        sysid=args.sysid,
        battery=args.battery,
        **kwargs,
    )
    vehicle.refuse_arm = args.refuse_arm
    with vehicle:
        print(f"READY udp={vehicle.udp_port} tcp={vehicle.tcp_port}", flush=True)
        while not stop.wait(0.2):
            pass
        snap = {
            **asdict(vehicle.snapshot()),
            "failsafe_modes": vehicle.failsafe_modes,
            "statustexts": vehicle.statustexts,
        }
    print(json.dumps(snap), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
