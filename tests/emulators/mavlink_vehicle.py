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
    for ``guided_timeout`` (3 s) the copter stops. A velocity target during the takeoff climb ends the
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
``udp_port``/``tcp_port`` after ``start()``.

Not emulated: missions, parameters, RC input, GCS/battery failsafes, message signing.

Faults: ``stop_heartbeats()`` (the link goes silent both ways: nothing is sent, nothing is received)
and ``resume_heartbeats()``; ``refuse_arm = True``; ``pilot_switch_mode("LOITER")`` (an RC mode switch:
no COMMAND_ACK, guided targets dropped); ``set_battery(pct)``.

CLI (to run it as a separate process, e.g. in a network namespace)::

    python -m tests.emulators.mavlink_vehicle --host 127.0.0.1 --udp-port 14550 --tcp-port 5760

prints ``READY udp=<port> tcp=<port>`` once listening and a JSON snapshot on SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import select
import signal
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav2

LOG = logging.getLogger("antalate.tests.mavlink_vehicle")

Address = tuple[str, int]

COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6,
    "CIRCLE": 7, "LAND": 9, "DRIFT": 11, "SPORT": 13, "FLIP": 14, "AUTOTUNE": 15, "POSHOLD": 16,
    "BRAKE": 17, "THROW": 18, "AVOID_ADSB": 19, "GUIDED_NOGPS": 20, "SMART_RTL": 21, "FLOWHOLD": 22,
    "FOLLOW": 23, "ZIGZAG": 24, "SYSTEMID": 25, "AUTOROTATE": 26, "AUTO_RTL": 27,
}
MODE_NAMES: dict[int, str] = {number: name for name, number in COPTER_MODES.items()}
# Modes that need a position estimate to be entered.
POSITION_MODES = frozenset(
    {"AUTO", "GUIDED", "LOITER", "RTL", "CIRCLE", "DRIFT", "POSHOLD", "BRAKE", "THROW", "AVOID_ADSB",
     "SMART_RTL", "FOLLOW", "ZIGZAG", "AUTO_RTL"}
)
# Modes ArduCopter will not arm in.
NOT_ARMABLE = frozenset(
    {"RTL", "LAND", "CIRCLE", "BRAKE", "SMART_RTL", "FLIP", "AUTOTUNE", "FOLLOW", "AUTO_RTL", "AVOID_ADSB"}
)

DEFAULT_RATES: dict[str, float] = {
    "GLOBAL_POSITION_INT": 5.0, "ATTITUDE": 5.0, "SYS_STATUS": 1.0, "EXTENDED_SYS_STATE": 1.0,
    "GPS_RAW_INT": 1.0, "EKF_STATUS_REPORT": 1.0, "VFR_HUD": 2.0, "LOCAL_POSITION_NED": 0.0,
    "HOME_POSITION": 0.0, "SYSTEM_TIME": 0.0,
}
# REQUEST_DATA_STREAM groups (ArduCopter's grouping, restricted to the messages emulated here).
DATA_STREAMS: dict[int, tuple[str, ...]] = {
    mav2.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT", "EXTENDED_SYS_STATE"),
    mav2.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    mav2.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    mav2.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    mav2.MAV_DATA_STREAM_EXTRA3: ("EKF_STATUS_REPORT", "SYSTEM_TIME"),
    mav2.MAV_DATA_STREAM_RAW_SENSORS: (),
    mav2.MAV_DATA_STREAM_RC_CHANNELS: (),
    mav2.MAV_DATA_STREAM_RAW_CONTROLLER: (),
}
FORCE_MAGIC = 21196  # param2 of ARM_DISARM that bypasses checks (ArduPilot convention)
EARTH_RADIUS = 6378137.0

_EKF_GOOD = (
    mav2.EKF_ATTITUDE | mav2.EKF_VELOCITY_HORIZ | mav2.EKF_VELOCITY_VERT | mav2.EKF_POS_HORIZ_REL
    | mav2.EKF_POS_HORIZ_ABS | mav2.EKF_POS_VERT_ABS | mav2.EKF_POS_VERT_AGL
    | mav2.EKF_PRED_POS_HORIZ_REL | mav2.EKF_PRED_POS_HORIZ_ABS
)
_EKF_NO_POSITION = mav2.EKF_ATTITUDE | mav2.EKF_VELOCITY_VERT | mav2.EKF_POS_VERT_ABS | mav2.EKF_CONST_POS_MODE
_SENSORS = (
    mav2.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav2.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mav2.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mav2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mav2.MAV_SYS_STATUS_SENSOR_GPS
)
_TM_POS = (
    mav2.POSITION_TARGET_TYPEMASK_X_IGNORE | mav2.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mav2.POSITION_TARGET_TYPEMASK_Z_IGNORE
)
_TM_VEL = (
    mav2.POSITION_TARGET_TYPEMASK_VX_IGNORE | mav2.POSITION_TARGET_TYPEMASK_VY_IGNORE
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
    rtl_phase: str | None  # climb | return | land (RTL only)


@dataclass(frozen=True)
class Received:
    """One message the vehicle received (for assertions)."""

    t: float  # time.monotonic()
    type: str
    fields: dict[str, Any]


class _Peer:
    """One transport endpoint with its own parser (MAVLink framing state is per stream)."""

    def __init__(self, sysid: int, compid: int, sock: socket.socket | None = None, addr: Address | None = None):
        self.sock = sock  # TCP client socket, None for UDP peers
        self.addr = addr
        self.parser = mav2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser.robust_parsing = True

    def parse(self, data: bytes) -> list[Any]:
        msgs = self.parser.parse_buffer(data) or []
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


class MavlinkVehicle:
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
        self.land_speed, self.land_speed_high, self.land_alt_low = land_speed, land_speed_high, land_alt_low
        self.rtl_speed, self.rtl_alt = rtl_speed, rtl_alt
        self.max_speed, self.max_climb_rate, self.max_descent_rate = max_speed, max_climb_rate, max_descent_rate
        self.velocity_tau = velocity_tau
        self.yaw_rate_max = yaw_rate_max
        self.guided_timeout = guided_timeout
        self.disarm_delay = disarm_delay
        self.land_detect_time = land_detect_time
        self.battery_drain = battery_drain
        self.tick_rate = tick_rate

        self.refuse_arm = False  # fault switch: arming answers FAILED while set

        self._lock = threading.RLock()
        self._stop_evt = threading.Event()
        self._thread: threading.Thread | None = None
        self._udp: socket.socket | None = None
        self._tcp: socket.socket | None = None
        self._udp_peers: dict[Address, _Peer] = {}
        self._tcp_peers: list[_Peer] = []
        self._wire = _WireBuffer()
        self._encoder = mav2.MAVLink(self._wire, srcSystem=sysid, srcComponent=compid)
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
        self._received: deque[Received] = deque(maxlen=20000)
        self._acks: list[tuple[int, int]] = []
        self._texts: list[str] = []

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self) -> MavlinkVehicle:
        """Bind the transports and power on (the boot/EKF/GPS clocks start now)."""
        if self._thread is not None:
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
            self._close_sockets()
            raise
        if self.udp_target is not None:
            self._udp_peers[self.udp_target] = _Peer(self.sysid, self.compid, addr=self.udp_target)
        with self._lock:
            self._t0 = time.monotonic()
            self._ground_since = self._t0
        self._stop_evt.clear()
        self._thread = threading.Thread(target=self._run, name="mavlink-vehicle", daemon=True)
        self._thread.start()
        LOG.info("MAVLink vehicle udp=%s tcp=%s", self.udp_port, self.tcp_port)
        return self

    def stop(self) -> None:
        """Stop the thread and close every socket (idempotent)."""
        self._stop_evt.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self._close_sockets()

    def __enter__(self) -> MavlinkVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

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
                booted=self._booted, system_status=self._system_status(now), mode=self._mode,
                custom_mode=COPTER_MODES[self._mode], armed=self._armed, landed_state=self._landed_state(),
                north=self._n, east=self._e, alt=-self._d, vn=self._vn, ve=self._ve, vd=self._vd,
                yaw=self._yaw % 360.0, lat=lat, lon=lon, battery=self._battery,
                gps_fix_type=3 if self._gps_fix(now) else 0, ekf_position_ok=self._position_ok(now),
                home=self._home, link_up=self._link_up,
                guided_submode=self._guided if self._mode == "GUIDED" else None,
                rtl_phase=self._rtl_phase if self._mode == "RTL" else None,
            )

    def wait_until(self, predicate: Callable[[VehicleSnapshot], bool], timeout: float) -> bool:
        """Poll ``predicate(snapshot())`` until true (True) or ``timeout`` s pass (False)."""
        deadline = time.monotonic() + timeout
        while True:
            if predicate(self.snapshot()):
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)

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

    # -- fault injection -------------------------------------------------------------------------

    def stop_heartbeats(self) -> None:
        """Link loss: stop every output (heartbeats included) and drop every input until resumed."""
        with self._lock:
            self._link_up = False

    def resume_heartbeats(self) -> None:
        with self._lock:
            self._link_up = True

    def pilot_switch_mode(self, mode: str) -> bool:
        """A pilot's RC mode switch: no COMMAND_ACK; GUIDED targets are dropped. False if refused."""
        with self._lock:
            return self._set_mode(mode.upper(), time.monotonic(), source="pilot") == mav2.MAV_RESULT_ACCEPTED

    def set_battery(self, pct: float) -> None:
        with self._lock:
            self._battery = max(0.0, min(100.0, float(pct)))

    # -- state helpers (lock held) -----------------------------------------------------------------

    def _gps_fix(self, now: float) -> bool:
        return now - self._t0 >= self.gps_delay

    def _position_ok(self, now: float) -> bool:
        return self._booted and self._gps_fix(now) and now - self._t0 >= self.ekf_delay

    def _system_status(self, now: float) -> int:
        if not self._booted:
            return mav2.MAV_STATE_BOOT if now - self._t0 < self.boot_delay / 2 else mav2.MAV_STATE_CALIBRATING
        return mav2.MAV_STATE_ACTIVE if self._armed else mav2.MAV_STATE_STANDBY

    def _landed_state(self) -> int:
        if not self._armed or (self._on_ground and self._takeoff_alt is None):
            return mav2.MAV_LANDED_STATE_ON_GROUND
        if self._mode == "GUIDED" and self._guided == "takeoff":
            return mav2.MAV_LANDED_STATE_TAKEOFF
        if self._mode == "LAND" or (self._mode == "RTL" and self._rtl_phase == "land"):
            return mav2.MAV_LANDED_STATE_LANDING
        return mav2.MAV_LANDED_STATE_IN_AIR

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
            return mav2.MAV_RESULT_FAILED
        if self._booted:
            if mode in POSITION_MODES and not self._position_ok(now):
                self._text(f"Flight mode change failed: {mode} requires position", mav2.MAV_SEVERITY_WARNING)
                return mav2.MAV_RESULT_FAILED
            if mode == "AUTO":
                self._text("Flight mode change failed: no mission", mav2.MAV_SEVERITY_WARNING)
                return mav2.MAV_RESULT_FAILED
        LOG.info("mode %s -> %s (%s)", self._mode, mode, source)
        self._mode = mode
        self._guided = "hover"
        self._target_vel = (0.0, 0.0, 0.0)
        self._target_pos = None
        self._target_yaw = None
        self._target_yaw_rate = 0.0
        self._rtl_phase = "climb" if mode == "RTL" else None
        self._takeoff_alt = None  # a mode change ends a guided takeoff
        return mav2.MAV_RESULT_ACCEPTED

    def _arm(self, force: bool, now: float) -> int:
        if self.refuse_arm:
            self._text("PreArm: fault injected (refuse_arm)", mav2.MAV_SEVERITY_CRITICAL)
            return mav2.MAV_RESULT_FAILED
        if not self._booted:
            self._text("PreArm: System not initialised", mav2.MAV_SEVERITY_CRITICAL)
            return mav2.MAV_RESULT_FAILED
        if self._armed:
            return mav2.MAV_RESULT_ACCEPTED
        if self._mode in NOT_ARMABLE:
            self._text("Arm: Mode not armable", mav2.MAV_SEVERITY_CRITICAL)
            return mav2.MAV_RESULT_FAILED
        if not force:
            if not self._gps_fix(now):
                self._text("PreArm: GPS 1: Bad fix", mav2.MAV_SEVERITY_CRITICAL)
                return mav2.MAV_RESULT_FAILED
            if not self._position_ok(now):
                self._text("PreArm: Need Position Estimate", mav2.MAV_SEVERITY_CRITICAL)
                return mav2.MAV_RESULT_FAILED
        self._armed = True
        self._ground_since = now
        if self._position_ok(now):
            self._set_home_here()
        self._text("Arming motors")
        return mav2.MAV_RESULT_ACCEPTED

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
            return mav2.MAV_RESULT_FAILED
        self._takeoff_alt = alt
        self._guided = "takeoff"
        return mav2.MAV_RESULT_ACCEPTED

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
            self._ack(msg, mav2.MAVLINK_MSG_ID_SET_MODE, mav2.MAV_RESULT_FAILED)
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
                return mav2.MAV_RESULT_FAILED
            self._disarm("command")
            return mav2.MAV_RESULT_ACCEPTED
        if cmd == mav2.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & mav2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return mav2.MAV_RESULT_FAILED
            return self._set_mode(MODE_NAMES.get(int(p[1]), ""), now, "DO_SET_MODE")
        if cmd == mav2.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(float(p[6]), now)
        if cmd == mav2.MAV_CMD_NAV_LAND:
            return self._set_mode("LAND", now, "NAV_LAND")
        if cmd == mav2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode("RTL", now, "NAV_RETURN_TO_LAUNCH")
        if cmd == mav2.MAV_CMD_CONDITION_YAW:
            return self._condition_yaw(p)
        if cmd == mav2.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(int(p[0]), p[1])
        if cmd == mav2.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(int(p[0]), now)
        if cmd == mav2.MAV_CMD_GET_HOME_POSITION:
            return self._request_message(mav2.MAVLINK_MSG_ID_HOME_POSITION, now)
        if cmd == mav2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return self._request_message(mav2.MAVLINK_MSG_ID_AUTOPILOT_VERSION, now)
        return mav2.MAV_RESULT_UNSUPPORTED

    def _condition_yaw(self, p: tuple[float, ...]) -> int:
        if self._mode != "GUIDED" or not self._armed or self._on_ground:
            return mav2.MAV_RESULT_FAILED
        angle, direction, relative = p[0], p[2], p[3]
        if relative:
            self._target_yaw = self._yaw + (angle if direction >= 0 else -angle)
        else:
            delta = (angle - self._yaw + 180.0) % 360.0 - 180.0
            self._target_yaw = self._yaw + delta
        self._target_yaw_rate = 0.0
        return mav2.MAV_RESULT_ACCEPTED

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        name = _MSG_NAMES.get(msg_id)
        if name is None or name not in self._rates:
            return mav2.MAV_RESULT_FAILED
        if interval_us < 0:
            rate = 0.0
        elif interval_us == 0:
            rate = self._default_rates[name]
        else:
            rate = 1e6 / interval_us
        self._rates[name] = rate
        self._next_send.pop(name, None)
        return mav2.MAV_RESULT_ACCEPTED

    def _request_message(self, msg_id: int, now: float) -> int:
        name = _MSG_NAMES.get(msg_id)
        if name is None or (name not in self._rates and name != "AUTOPILOT_VERSION"):
            return mav2.MAV_RESULT_UNSUPPORTED
        if name == "HOME_POSITION" and self._home is None:
            return mav2.MAV_RESULT_FAILED
        self._after_ack.append(self._make(name, now))
        return mav2.MAV_RESULT_ACCEPTED

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
            mav2.MAV_FRAME_LOCAL_NED, mav2.MAV_FRAME_LOCAL_OFFSET_NED, mav2.MAV_FRAME_BODY_NED,
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

    _HANDLERS: dict[str, Callable[[MavlinkVehicle, Any, float], None]] = {
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
                if now - self._last_target > self.guided_timeout:
                    self._guided = "hover"  # ArduCopter's guided timeout: stop
                    self._target_yaw_rate, self._target_yaw = 0.0, None
                elif self._guided == "position" and self._target_pos is not None:
                    tn, te, td = self._target_pos
                    vel = (1.0 * (tn - self._n), 1.0 * (te - self._e), 1.0 * (td - self._d))
                else:
                    vel = self._target_vel
            yaw_rate = self._yaw_control()
        elif self._mode == "RTL":
            vel = self._rtl(alt)
        elif self._mode == "LAND":
            vel = (0.0, 0.0, self._land_rate(alt))
        return self._limit(vel), yaw_rate

    def _yaw_control(self) -> float:
        if self._target_yaw is not None:
            err = self._target_yaw - self._yaw
            rate = math.copysign(max(abs(4.0 * err), 30.0), err)  # slows down near the target, then snaps
            return max(-self.yaw_rate_max, min(self.yaw_rate_max, rate))
        return max(-self.yaw_rate_max, min(self.yaw_rate_max, self._target_yaw_rate))

    def _rtl(self, alt: float) -> tuple[float, float, float]:
        hn, he = self._home_ned()
        if self._rtl_phase == "climb":
            if alt < self.rtl_alt - 0.1:
                return (0.0, 0.0, -self.max_climb_rate)
            self._rtl_phase = "return"
        if self._rtl_phase == "return":
            dn, de = hn - self._n, he - self._e
            dist = math.hypot(dn, de)
            if dist > 0.3:
                speed = min(self.rtl_speed, 2.5 * dist)
                return (dn / dist * speed, de / dist * speed, 0.0)
            self._rtl_phase = "land"
        return (0.0, 0.0, self._land_rate(alt))

    def _land_rate(self, alt: float) -> float:
        return self.land_speed_high if alt > self.land_alt_low else self.land_speed

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

    def _make(self, name: str, now: float) -> Any:
        """Encode one telemetry message from the current state (lock held)."""
        enc = self._encoder
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        pos_ok = self._position_ok(now)
        lat, lon = self._latlon() if pos_ok else (0.0, 0.0)
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
                mav2.MAV_TYPE_QUADROTOR, mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, base, COPTER_MODES[self._mode],
                self._system_status(now), 3,
            )
        if name == "GLOBAL_POSITION_INT":
            return enc.global_position_int_encode(
                boot_ms, round(lat * 1e7), round(lon * 1e7), round((self.origin[2] + alt) * 1000),
                round((self.origin[2] + alt - home_alt) * 1000), round(self._vn * 100), round(self._ve * 100),
                round(self._vd * 100), round(self._yaw % 360.0 * 100) % 36000,
            )
        if name == "ATTITUDE":
            fwd = self._vn * math.cos(yaw_rad) + self._ve * math.sin(yaw_rad)
            right = -self._vn * math.sin(yaw_rad) + self._ve * math.cos(yaw_rad)
            return enc.attitude_encode(
                boot_ms, math.radians(2.0 * right), math.radians(-2.0 * fwd), yaw_rad, 0.0, 0.0,
                math.radians(self._yaw_rate),
            )
        if name == "SYS_STATUS":
            health = _SENSORS if self._gps_fix(now) else _SENSORS & ~mav2.MAV_SYS_STATUS_SENSOR_GPS
            if pos_ok and not self.refuse_arm:
                health |= mav2.MAV_SYS_STATUS_PREARM_CHECK
            volts = 12.6 - 0.03 * (100.0 - self._battery)
            current = 1500 if self._armed else 50  # cA
            return enc.sys_status_encode(
                _SENSORS | mav2.MAV_SYS_STATUS_PREARM_CHECK, _SENSORS | mav2.MAV_SYS_STATUS_PREARM_CHECK,
                health, 150, round(volts * 1000), current, round(self._battery), 0, 0, 0, 0, 0, 0,
            )
        if name == "EXTENDED_SYS_STATE":
            return enc.extended_sys_state_encode(mav2.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if name == "GPS_RAW_INT":
            if self._gps_fix(now):
                glat, glon = self._latlon()
                return enc.gps_raw_int_encode(
                    int((now - self._t0) * 1e6), mav2.GPS_FIX_TYPE_3D_FIX, round(glat * 1e7), round(glon * 1e7),
                    round((self.origin[2] + alt) * 1000), 70, 120, round(math.hypot(self._vn, self._ve) * 100),
                    round(math.degrees(math.atan2(self._ve, self._vn)) % 360.0 * 100) % 36000, 12,
                )
            return enc.gps_raw_int_encode(int((now - self._t0) * 1e6), mav2.GPS_FIX_TYPE_NO_GPS, 0, 0, 0,
                                          65535, 65535, 0, 65535, 0)
        if name == "EKF_STATUS_REPORT":
            if not self._booted:
                return enc.ekf_status_report_encode(mav2.EKF_UNINITIALIZED, 1.0, 1.0, 1.0, 1.0, 0.0)
            if pos_ok:
                return enc.ekf_status_report_encode(_EKF_GOOD, 0.02, 0.03, 0.02, 0.05, 0.0)
            return enc.ekf_status_report_encode(_EKF_NO_POSITION, 0.1, 1.0, 0.1, 0.1, 0.0)
        if name == "VFR_HUD":
            speed = math.hypot(self._vn, self._ve)
            return enc.vfr_hud_encode(speed, speed, round(self._yaw % 360.0) % 360, 40 if self._armed and not
                                      self._on_ground else 0, self.origin[2] + alt, -self._vd)
        if name == "LOCAL_POSITION_NED":
            return enc.local_position_ned_encode(boot_ms, self._n, self._e, self._d, self._vn, self._ve, self._vd)
        if name == "HOME_POSITION":
            hlat, hlon, halt = self._home or (self.origin[0], self.origin[1], self.origin[2])
            hn, he = self._home_ned()
            return enc.home_position_encode(
                round(hlat * 1e7), round(hlon * 1e7), round(halt * 1000), hn, he, -(halt - self.origin[2]),
                [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int((now - self._t0) * 1e6),
            )
        if name == "SYSTEM_TIME":
            return enc.system_time_encode(int(time.time() * 1e6), boot_ms)
        if name == "AUTOPILOT_VERSION":
            caps = (
                mav2.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mav2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | mav2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
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
                self._outbox.append(self._make(name, now))
                # keep the cadence without bursts after a stall
                self._next_send[name] = max(due + 1.0 / rate, now)

    def _flush(self) -> None:
        with self._lock:
            outbox, self._outbox = self._outbox, []
            link_up = self._link_up
            for msg in outbox:
                self._encoder.send(msg)
            wire = self._wire.take()
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

    # -- the I/O thread ------------------------------------------------------------------------------

    def _run(self) -> None:
        tick = 1.0 / self.tick_rate
        last = time.monotonic()
        next_tick = last
        while not self._stop_evt.is_set():
            socks = [s for s in (self._udp, self._tcp) if s is not None]
            socks += [p.sock for p in self._tcp_peers if p.sock is not None]
            try:
                ready, _, _ = select.select(socks, [], [], max(0.0, min(next_tick - time.monotonic(), 0.05)))
            except (OSError, ValueError):
                ready = []
                self._tcp_peers = [p for p in self._tcp_peers if p.sock is not None and p.sock.fileno() >= 0]
            for sock in ready:
                self._read(sock)
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
            self._tcp_peers.append(_Peer(self.sysid, self.compid, sock=conn))
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
                peer = self._udp_peers[addr] = _Peer(self.sysid, self.compid, addr=addr)
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
        with self._lock:
            if not self._link_up:
                return
            for msg in peer.parse(data):
                self._handle(msg, now)

    def _drop_tcp(self, peer: _Peer) -> None:
        if peer in self._tcp_peers:
            self._tcp_peers.remove(peer)
        if peer.sock is not None:
            peer.sock.close()

    def _close_sockets(self) -> None:
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
    parser = argparse.ArgumentParser(prog="python -m tests.emulators.mavlink_vehicle", description=__doc__.split("\n")[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--udp-port", type=int, default=0, help="-1 disables UDP")
    parser.add_argument("--tcp-port", type=int, default=-1, help="-1 disables TCP, 0 picks a free port")
    parser.add_argument("--udp-target", default=None, help="HOST:PORT to push to (like SITL's udpclient)")
    parser.add_argument("--home", default=None, help="LAT,LON[,ALT]")
    parser.add_argument("--boot-delay", type=float, default=0.5)
    parser.add_argument("--ekf-delay", type=float, default=1.0)
    parser.add_argument("--gps-delay", type=float, default=1.0)
    parser.add_argument("--battery", type=float, default=100.0)
    parser.add_argument("--refuse-arm", action="store_true")
    parser.add_argument("--log-level", default="WARNING")
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(name)s %(message)s")

    kwargs: dict[str, Any] = {}
    if args.home:
        parts = [float(v) for v in args.home.split(",")]
        kwargs.update(home_lat=parts[0], home_lon=parts[1])
        if len(parts) > 2:
            kwargs["home_alt"] = parts[2]
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
        boot_delay=args.boot_delay, ekf_delay=args.ekf_delay, gps_delay=args.gps_delay, battery=args.battery,
        **kwargs,
    )
    vehicle.refuse_arm = args.refuse_arm
    with vehicle:
        print(f"READY udp={vehicle.udp_port} tcp={vehicle.tcp_port}", flush=True)
        while not stop.wait(0.2):
            pass
        snap = asdict(vehicle.snapshot())
    print(json.dumps(snap), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
