"""A Crazyflie emulator speaking CRTP over UDP, as simulators do for cflib's ``udp://`` driver.

It is modelled on bitcraze/crazyflie-firmware (src/modules/src/log.c, param_logic.c, crtpservice.c,
platformservice.c, crtp_commander_generic.c, crtp_commander.c, commander.c,
crtp_commander_high_level.c, planner.c, crtp_supervisor.c, supervisor.c,
supervisor_state_machine.c, stabilizer.c, hal/src/pm_stm32f4.c) and on what cflib 0.1.34 sends, so
tests drive the real cflib. The behaviours below were checked against the firmware at tag 2026.08
(commit 2a18fc29); "(file)" after each says where:

* **Framing** (cflib/crtp/udpdriver.py): one CRTP packet per datagram, byte 0 the header
  ``port << 4 | 0x0C | channel``, then up to 30 bytes of payload; no checksum. Replies go to the
  address of the last datagram received. With ``memory=NAME`` the same bytes go over a
  ``memory://NAME`` link instead (`antalate_lcm.vehicles.crazyflie.memory`): no socket at all.
* **Link** (port 15): channel 0 echoes (cflib's latency pings), channel 1 ("source") answers the
  30-byte "Bitcraze Crazyflie" string, which tells cflib the firmware has protocol versioning;
  the null packet ``0xFF`` (cflib's UDP scan) gets an empty ``0xFF`` back.
* **Platform** (port 13, channel 1): protocol version (int32, 12 as today's firmware) and firmware
  version string.
* **Memory** (port 4): no memories (cflib only counts them during connection).
* **Log** (port 5): the TOC in its V2 form (``CMD_GET_INFO_V2``: count, CRC32, max blocks, max ops;
  ``CMD_GET_ITEM_V2``: id, type, ``group\\0name\\0``) with the firmware's CRC -- zlib's CRC32 chained
  over every TOC entry (``crc(prev_crc LE32 + type byte + name)``, group start/stop markers
  included, type with its CORE/GROUP flags). Blocks: create/append V2 (3-byte ``logType, id``
  settings), start (period in 10 ms), start V2 (period in ms), stop, delete, reset; each answered
  ``(cmd, block id, errno)``. A started block streams ``id, 24-bit ms timestamp, values`` every period.
* **Param** (port 2): TOC V2 (CRC as for the log), read (``id, 0, value``), write (the packet echoed
  back after the value is set).
* **Generic commander** (port 7): channel 0 set-points ``TYPE_STOP``, ``TYPE_VELOCITY_WORLD`` (8:
  vx, vy, vz m/s, yaw rate deg/s), ``TYPE_HOVER`` (10: body vx, vy, yaw rate, absolute height);
  channel 1 ``notify setpoint stop``. A streamed set-point has a higher priority than the
  high-level commander and *stops its planner* (commander.c ``commanderSetSetpoint`` calls
  ``crtpCommanderHighLevelStop``, PR #1298); high-level set-points are ignored while it streams.
  ``notify setpoint stop`` only relaxes the priority (crtp_commander.c -> commander.c
  ``commanderRelaxPriority``): a stopped planner then sends the *null set-point* -- motors off
  (crtp_commander_high_level.c ``crtpCommanderHighLevelGetSetpoint``: "when the HLcommander is
  stopped, it wants the motors to be off") -- until the next high-level command. A flying
  Crazyflie that gets a notify and no high-level command falls (`falls` counts it); one that gets
  the command within its fall (a few ms on a radio) recovers where it is.
* **Commander watchdog** (supervisor.c ``COMMANDER_WDT_TIMEOUT_STABILIZE`` 500 ms /
  ``_SHUTDOWN`` 2000 ms, supervisor_state_machine.c, ``supervisorOverrideSetpoint``): a streamed
  set-point older than 0.5 s puts the supervisor in WarningLevelOut -- x/y control off, roll and
  pitch level, yaw rate 0, *z kept as it was* (the last vertical velocity of a world set-point, the
  last height of a hover set-point); the horizontal velocity then only coasts (no tilt, drag not
  modelled). Older than 2 s: ExceptFreeFall, then Locked -- motors off, it falls, reboot required.
* **Legacy commander** (port 3, roll/pitch/yaw-rate/thrust): only what cflib sends itself -- its
  ``close_link`` sends ``send_setpoint(0, 0, 0, 0)``, a zero-thrust set-point that stops flying motors
  (attitude flight is not modelled: any other thrust is ignored).
* **High-level commander** (port 8): ``takeoff2``, ``land2``, ``go_to`` (4) and ``go_to2`` (12),
  ``stop``. Trajectories are smooth (quintic minimum-jerk) between the current and target poses
  over the given duration; landing ends with the planner idle, so the motors stop (the null
  set-point), and ``landed_timeout`` (3 s, platform_defaults.h ``LANDING_TIMEOUT_MS``) later the
  supervisor disarms. **Every packet is answered** (crtp_commander_high_level.c
  ``crtpCommanderHighLevelTask``: the first three bytes back, byte 3 the result): 0, or 1 when the
  planner refuses -- ``takeoff`` unless the planner is idle (so a take-off while flying a
  trajectory), ``land`` while landing (planner.c ``plan_takeoff``/``plan_land``) -- or ``EBUSY``
  (16) while the supervisor says it cannot fly (stabilizer.c ``crtpCommanderBlock(!canFly)``), or
  ``ENOEXEC`` (8) for an unknown command. `hl_answers` keeps them.
* **Flying bit** (supervisor.c ``isFlyingCheck``, ``IS_FLYING_HYSTERESIS_THRESHOLD`` 2 s): thrust over
  idle, or within 2 s since there was -- ``sys.isFlying`` and the bitfield's "is flying" stay set 2 s
  after the motors stop (a landing, a fall), and the supervisor enters Landed (its landed timeout's
  start, supervisor_state_machine.c) only then. `flying` is the truth (the motors turn).
* **Supervisor** (port 9): state bitfield request (``0x0C`` -> ``0x8C`` + uint16), arm/disarm
  (``0x01`` -> ``0x81, success, is_armed``; refused while locked), emergency stop (``0x03``:
  motors off, locked). **Auto-arming** (``auto_arming``, default on: Kconfig
  ``MOTORS_REQUIRE_ARMING`` defaults to n on a CF2.x, supervisor.c ``AUTO_ARMING``): the supervisor
  arms itself whenever its pre-flight checks pass -- at power-on, after a disarm request, after the
  landed timeout -- within ``rearm_delay``; only a lock (or a crash) keeps it disarmed.
* **Power** (hal/src/pm_stm32f4.c ``pmTask``, platform_defaults_cf2.h): ``pm.state`` becomes
  lowPower (3) once ``pm.vbat`` has been below 3.2 V for 5 s (``DEFAULT_BAT_LOW_VOLTAGE``,
  ``DEFAULT_BAT_LOW_DURATION_TO_TRIGGER_SEC``); in lowPower, 5 s below 3.0 V
  (``DEFAULT_BAT_CRITICAL_LOW_VOLTAGE``) calls ``pmSystemShutdown``, which powers the Crazyflie
  off only in a build with ``CONFIG_PM_AUTO_SHUTDOWN`` (Kconfig default n): ``auto_shutdown=True``
  models such a build -- motors off (it falls) and the radio dead (`shut_down`). A default build
  flies on, its LiPo below 3.0 V.

The vehicle is a point mass in the Crazyflie world frame (x, y, z up; yaw in degrees,
counter-clockwise) with a first-order velocity response to set-points; with its motors off in the
air it falls at 1 g. Its battery (``pm.vbat``) drains while the motors run; ``pm.batteryLevel``
follows the firmware's LiPo charge curve. The Kalman estimator's position variances
(``kalman.varPX/PY/PZ``) are what ``converged`` sets.

Fault knobs: ``set_silent(True)`` (the radio is gone both ways; ``dropped`` counts what it ate), ``set_battery(volts)``,
``set_locked(True)`` (the supervisor refuses to arm, so a take-off cannot happen),
``set_converged(False)`` (the estimator's variances stay large), ``drain`` (V/s in flight),
``drop_next(port, count)`` (the next `count` packets to `port` are lost on the way in: one lost
high-level command), ``auto_arming`` / ``auto_shutdown`` (the build options above). Over a
``radio://`` link (`tests.emulators.crazyradio`) silence is what makes cflib's radio driver give up.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from tests.emulators.lifecycle import Emulator, Motion

if TYPE_CHECKING:  # cflib only when a memory link is asked for
    from antalate_lcm.vehicles.crazyflie.memory import MemoryLink

Address = tuple[str, int]
_MEMORY_PEER: Address = ("memory", 0)  # the sender of packets off a memory link
_RADIO_PEER: Address = ("radio", 0)  # the sender of packets off a Crazyradio (tests/emulators/crazyradio.py)

# CRTP ports (cflib/crtp/crtpstack.py)
PORT_PARAM, PORT_COMMANDER, PORT_MEM, PORT_LOG, PORT_GENERIC, PORT_HL, PORT_SUPERVISOR = 2, 3, 4, 5, 7, 8, 9
PORT_PLATFORM, PORT_LINK = 13, 15

# log.h types and flags
LOG_UINT8, LOG_UINT16, LOG_UINT32, LOG_INT8, LOG_INT16, LOG_INT32, LOG_FLOAT, LOG_FP16 = range(1, 9)
LOG_CORE, LOG_GROUP, LOG_START = 0x20, 0x80, 1
LOG_FORMATS = {
    LOG_UINT8: "<B",
    LOG_UINT16: "<H",
    LOG_UINT32: "<I",
    LOG_INT8: "<b",
    LOG_INT16: "<h",
    LOG_INT32: "<i",
    LOG_FLOAT: "<f",
    LOG_FP16: "<e",
}
# param.h types and flags
PARAM_UINT8, PARAM_UINT16, PARAM_FLOAT = 0x08, 0x09, 0x06
PARAM_CORE, PARAM_GROUP, PARAM_START = 0x20, 0x80, 1
PARAM_FORMATS = {0x08: "<B", 0x09: "<H", 0x0A: "<I", 0x00: "<b", 0x01: "<h", 0x02: "<i", 0x06: "<f"}

PROTOCOL_VERSION = 12  # src/modules/interface/crtp.h
FIRMWARE_VERSION = "2026.08"  # the tag the behaviours below were read at
LOG_MAX_BLOCKS, LOG_MAX_OPS = 16, 128
WDT_STABILIZE, WDT_SHUTDOWN = 0.5, 2.0  # supervisor.c COMMANDER_WDT_TIMEOUT_*
FLYING_HYSTERESIS = 2.0  # supervisor.c IS_FLYING_HYSTERESIS_THRESHOLD: "flying" this long after thrust
LOW_VOLTAGE, CRITICAL_LOW_VOLTAGE = 3.2, 3.0  # platform_defaults_cf2.h DEFAULT_BAT_(CRITICAL_)LOW_VOLTAGE
LOW_DURATION = 5.0  # platform_defaults_cf2.h DEFAULT_BAT_LOW_DURATION_TO_TRIGGER_SEC (both timers)
LANDING_TIMEOUT = 3.0  # platform_defaults.h LANDING_TIMEOUT_MS: landed this long -> disarm
GRAVITY = 9.81
# crtp_commander_high_level.c answers: 0, planner.c's refusal (1), errno
HL_OK, HL_REFUSED, HL_ENOEXEC, HL_EBUSY = 0, 1, 8, 16
PM_BATTERY, PM_LOW_POWER = 0, 3  # pm.h PMStates
#: pm_stm32f4.c LiPoTypicalChargeCurve: the voltage of 0%, 10%, ... 90%.
CHARGE_CURVE = (3.00, 3.78, 3.83, 3.87, 3.89, 3.92, 3.96, 4.00, 4.04, 4.10)

# supervisor bitfield bits (cflib/crazyflie/supervisor.py, firmware supervisor.h)
BIT_CAN_BE_ARMED, BIT_IS_ARMED, BIT_CAN_FLY, BIT_IS_FLYING = 0, 1, 3, 4
BIT_IS_TUMBLED, BIT_IS_LOCKED, BIT_IS_CRASHED = 5, 6, 7
BIT_HL_ACTIVE, BIT_HL_FINISHED, BIT_HL_DISABLED = 8, 9, 10


def battery_level(volts: float) -> int:
    """``pm.batteryLevel`` as the firmware computes it: the charge-curve step times ten (0..90)."""
    if volts < CHARGE_CURVE[0]:
        return 0
    if volts > CHARGE_CURVE[9]:
        return 90
    charge = 0
    while volts > CHARGE_CURVE[charge]:
        charge += 1
    return charge * 10


@dataclass(frozen=True)
class TocEntry:
    """One entry of a firmware log/param section: a group marker or a variable."""

    type: int
    name: str
    group: str = ""  # the variable's group (empty for markers)


def toc_entries(
    groups: list[tuple[str, list[tuple[int, str]]]], group_flag: int, start_flag: int
) -> list[TocEntry]:
    """The linker-section order: ``GROUP_START(g)``, its variables, ``GROUP_STOP(g)`` named ``stop_g``."""
    out: list[TocEntry] = []
    for group, variables in groups:
        out.append(TocEntry(group_flag | start_flag, group))
        out.extend(TocEntry(t, name, group) for t, name in variables)
        out.append(TocEntry(group_flag, f"stop_{group}"))
    return out


def toc_crc(entries: list[TocEntry]) -> int:
    """log.c/param_logic.c: crc32 of (previous crc, LE32) + type byte + name, chained over the entries."""
    crc = 0
    for e in entries:
        crc = zlib.crc32(struct.pack("<IB", crc, e.type & 0xFF) + e.name.encode())
    return crc


LOG_GROUPS: list[tuple[str, list[tuple[int, str]]]] = [
    (
        "stateEstimate",
        [(LOG_FLOAT | LOG_CORE, n) for n in ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw")],
    ),
    (
        "pm",
        [
            (LOG_FLOAT | LOG_CORE, "vbat"),
            (LOG_UINT16, "vbatMV"),
            (LOG_INT8 | LOG_CORE, "state"),
            (LOG_UINT8 | LOG_CORE, "batteryLevel"),
        ],
    ),
    ("kalman", [(LOG_FLOAT, "varPX"), (LOG_FLOAT, "varPY"), (LOG_FLOAT, "varPZ")]),
    (
        "sys",
        [
            (LOG_UINT8 | LOG_CORE, "canfly"),
            (LOG_UINT8 | LOG_CORE, "isFlying"),
            (LOG_UINT8 | LOG_CORE, "isTumbled"),
        ],
    ),
    ("supervisor", [(LOG_UINT16, "info")]),
]
PARAM_GROUPS: list[tuple[str, list[tuple[int, str]]]] = [
    ("commander", [(PARAM_UINT8 | PARAM_CORE, "enHighLevel")]),
    (
        "stabilizer",
        [
            (PARAM_UINT8 | PARAM_CORE, "estimator"),
            (PARAM_UINT8 | PARAM_CORE, "controller"),
            (PARAM_UINT8 | PARAM_CORE, "stop"),
        ],
    ),
    ("kalman", [(PARAM_UINT8, "resetEstimation")]),
]


@dataclass
class _Block:
    ops: list[tuple[int, int]] = field(default_factory=list)  # (fetch type, variable index)
    period: float = 0.0
    next_at: float = math.inf


@dataclass
class _Trajectory:
    kind: str  # "takeoff", "land", "goto"
    start: tuple[float, float, float, float]  # x, y, z, yaw
    end: tuple[float, float, float, float]
    t0: float
    duration: float


def _minimum_jerk(s: float) -> tuple[float, float]:
    """Position and velocity fractions of a rest-to-rest quintic at normalised time ``s``."""
    s = min(max(s, 0.0), 1.0)
    return 10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4


@dataclass(frozen=True)
class CrazyflieSnapshot(Motion):
    vbat: float
    armed: bool
    flying: bool
    locked: bool
    streaming: bool
    hl_kind: str


class CrazyflieEmulator(Emulator["CrazyflieSnapshot"]):
    """One emulated Crazyflie on a UDP port (``udp://127.0.0.1:PORT``). Use as a context manager."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        x: float = 0.0,
        y: float = 0.0,
        yaw: float = 0.0,
        voltage: float = 4.1,
        drain: float = 0.0,
        velocity_tau: float = 0.1,
        landed_timeout: float = LANDING_TIMEOUT,
        converged: bool = True,
        locked: bool = False,
        auto_arming: bool = True,
        rearm_delay: float = 0.1,
        auto_shutdown: bool = False,
        clock: Callable[[], float] = time.monotonic,
        memory: str | None = None,
        radio: bool = False,
    ) -> None:
        """Bind ``host:port`` (``udp://``), or with `memory` register ``memory://MEMORY`` and bind nothing,
        or with `radio` bind nothing and answer `radio_exchange` (a `crazyradio.Crazyradio` calls it)."""
        super().__init__()
        self.clock = clock
        self._lock = threading.RLock()
        self._sock: socket.socket | None = None
        self._memory: MemoryLink | None = None
        #: over a radio, replies wait here for the next acknowledgement to carry them
        self._radio_out: deque[bytes] | None = deque() if radio else None
        self.radio_uri = ""  # set by the dongle the emulator is added to
        if memory is not None:
            from antalate_lcm.vehicles.crazyflie.memory import MemoryLink

            self._memory = MemoryLink(memory, lambda packet: self._on_datagram(packet, _MEMORY_PEER))
        elif not radio:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._sock.bind((host, port))
            self._sock.settimeout(0.1)
        self._peer: Address | None = None
        self._boot = clock()
        # vehicle
        self.x, self.y, self.z, self.yaw = x, y, 0.0, yaw
        self.vx = self.vy = self.vz = 0.0
        self.vbat = voltage
        self.drain = drain
        self.velocity_tau = velocity_tau
        self.landed_timeout = landed_timeout
        self.auto_arming = auto_arming
        self.rearm_delay = rearm_delay
        self.auto_shutdown = auto_shutdown
        self.armed = False
        self._disarmed_at = clock()  # auto-arming re-arms rearm_delay after this
        self.motors = False
        self.locked = locked
        self.crashed = False
        self.converged = converged
        self.silent = False
        self.shut_down = False  # pmSystemShutdown in an auto_shutdown build: powered off for good
        self._low_since = clock() if voltage < LOW_VOLTAGE else math.inf  # pm_stm32f4.c batteryLowTimeStamp
        self._critical_since = clock() if voltage < CRITICAL_LOW_VOLTAGE else math.inf
        self._drop: dict[int, int] = {}  # port -> packets still to lose on the way in
        self._traj: _Trajectory | None = None
        self._traj_finished = False
        self._landed_at: float | None = None
        self._thrust_at = -math.inf  # clock() when the motors last ran (the flying bit's hysteresis)
        self._streaming = False
        self._sp_kind = ""  # "world" or "hover"
        self._sp: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self._sp_at = 0.0
        # TOCs
        self.log_entries = toc_entries(LOG_GROUPS, LOG_GROUP, LOG_START)
        self.log_vars = [e for e in self.log_entries if not e.type & LOG_GROUP]
        self.log_crc = toc_crc(self.log_entries)
        self.param_entries = toc_entries(PARAM_GROUPS, PARAM_GROUP, PARAM_START)
        self.param_vars = [e for e in self.param_entries if not e.type & PARAM_GROUP]
        self.param_crc = toc_crc(self.param_entries)
        self.params: dict[str, float] = {
            "commander.enHighLevel": 0,
            "stabilizer.estimator": 2,
            "stabilizer.controller": 1,
            "stabilizer.stop": 0,
            "kalman.resetEstimation": 0,
        }
        self._blocks: dict[int, _Block] = {}
        # what was received, for tests
        self.received: list[tuple[int, int, bytes]] = []
        self.hl_commands: list[tuple[str, tuple[float, ...]]] = []
        self.hl_answers: list[tuple[str, int]] = []  # (command, result) as answered on port 8
        self.falls = 0  # times it hit the floor with its motors off (null set-point, watchdog, stop)
        self.setpoints = 0
        self.dropped = 0  # datagrams lost to silence
        self.notify_stops = 0
        self.emergency_stops = 0

    # ------------------------------------------------------------------ lifecycle
    @property
    def port(self) -> int:
        assert self._sock is not None, "an emulator on a memory link has no port"
        return int(self._sock.getsockname()[1])

    @property
    def uri(self) -> str:
        if self._memory is not None:
            return self._memory.uri
        if self._radio_out is not None:
            return self.radio_uri
        assert self._sock is not None
        host, port = self._sock.getsockname()[:2]
        return f"udp://{host}:{port}"

    def start(self) -> CrazyflieEmulator:
        if self._workers.running:
            return self
        loops = [(self._sim_loop, "cf-emu-sim")]
        if self._sock is not None:
            loops.append((self._recv_loop, "cf-emu-rx"))
        self._workers.start(*loops)
        return self

    def _close_transports(self) -> None:
        if self._sock is not None:
            self._sock.close()
        if self._memory is not None:
            self._memory.close()

    # ------------------------------------------------------------------ knobs and views
    def set_silent(self, silent: bool) -> None:
        with self._lock:
            self.silent = silent

    def set_battery(self, volts: float) -> None:
        with self._lock:
            self.vbat = volts
            self._track_battery(self.clock())

    def drop_next(self, port: int, count: int = 1) -> None:
        """Lose the next `count` packets to CRTP `port` on the way in (one lost command)."""
        with self._lock:
            self._drop[port] = self._drop.get(port, 0) + count

    def set_locked(self, locked: bool) -> None:
        with self._lock:
            self.locked = locked

    def set_converged(self, converged: bool) -> None:
        with self._lock:
            self.converged = converged

    def snapshot(self) -> CrazyflieSnapshot:
        with self._lock:
            return CrazyflieSnapshot(
                self.x,
                self.y,
                self.z,
                self.yaw,
                self.vx,
                self.vy,
                self.vz,
                self.vbat,
                self.armed,
                self.flying,
                self.locked,
                self._streaming,
                self._traj.kind if self._traj else "",
            )

    @property
    def flying(self) -> bool:
        """The motors turn: the vehicle's truth (also on the first centimetres)."""
        return self.motors

    def flying_bit(self) -> bool:
        """supervisor.c isFlyingCheck, as reported: thrust over idle, *or* within the 2 s since it was
        (``IS_FLYING_HYSTERESIS_THRESHOLD``) -- a Crazyflie reads flying 2 s after its motors stop, and
        the supervisor goes Flying -> Landed (supervisor_state_machine.c) only then."""
        return self.motors or self.clock() - self._thrust_at < FLYING_HYSTERESIS

    @property
    def pm_state(self) -> int:
        """pm_stm32f4.c pmUpdateState: lowPower once below the low voltage for LOW_DURATION."""
        return PM_LOW_POWER if self.clock() - self._low_since > LOW_DURATION else PM_BATTERY

    def supervisor_info(self) -> int:
        bits = 0
        can_arm = not self.locked and not self.crashed
        flags = {
            BIT_CAN_BE_ARMED: can_arm,
            BIT_IS_ARMED: self.armed,
            BIT_CAN_FLY: self.armed and can_arm,
            BIT_IS_FLYING: self.flying_bit(),
            BIT_IS_TUMBLED: self.crashed,
            BIT_IS_LOCKED: self.locked,
            BIT_IS_CRASHED: self.crashed,
            # supervisor.c updateLogData: the planner flying or landing; a stream stops it (never
            # "disabled" since PR #1298)
            BIT_HL_ACTIVE: self._traj is not None,
            BIT_HL_FINISHED: self._traj_finished,
            BIT_HL_DISABLED: False,
        }
        for bit, on in flags.items():
            bits |= int(on) << bit
        return bits

    def log_value(self, name: str) -> float:
        """The current value of a log variable ``group.name``."""
        variance = 1e-5 if self.converged else 2.5
        values: dict[str, float] = {
            "stateEstimate.x": self.x,
            "stateEstimate.y": self.y,
            "stateEstimate.z": self.z,
            "stateEstimate.vx": self.vx,
            "stateEstimate.vy": self.vy,
            "stateEstimate.vz": self.vz,
            "stateEstimate.roll": 0.0,
            "stateEstimate.pitch": 0.0,
            "stateEstimate.yaw": self.yaw,
            "pm.vbat": self.vbat,
            "pm.vbatMV": round(self.vbat * 1000),
            "pm.state": self.pm_state,
            "pm.batteryLevel": battery_level(self.vbat),
            "kalman.varPX": variance,
            "kalman.varPY": variance,
            "kalman.varPZ": variance,
            "sys.canfly": int(self.armed and not self.locked),
            "sys.isFlying": int(self.flying_bit()),
            "sys.isTumbled": int(self.crashed),
            "supervisor.info": self.supervisor_info(),
        }
        return values[name]

    # ------------------------------------------------------------------ I/O
    def _send(self, port: int, channel: int, data: bytes) -> None:
        if self.silent or self.shut_down or self._peer is None:
            return
        packet = bytes([(port << 4) | 0x0C | channel]) + data[:30]
        if self._radio_out is not None:
            self._radio_out.append(packet)
            return
        if self._memory is not None:
            self._memory.push(packet)
            return
        with contextlib.suppress(OSError):
            if self._sock is not None:
                self._sock.sendto(packet, self._peer)

    def _recv_loop(self) -> None:
        assert self._sock is not None
        while not self._workers.stop.is_set():
            try:
                data, sender = self._sock.recvfrom(64)
            except TimeoutError:
                continue
            except OSError:
                return
            self._on_datagram(data, sender)

    def radio_exchange(self, packet: bytes) -> bytes | None:
        """One radio packet from the host: the ack payload (the next queued reply, maybe empty), or
        None when the radio does not acknowledge (silent, powered off)."""
        with self._lock:
            if self.silent or self.shut_down:
                self.dropped += 1
                return None
            if packet and packet[0] != 0xFF:  # 0xFF...: a null poll (or the safelink handshake)
                self._on_datagram(packet, _RADIO_PEER)
            self._peer = _RADIO_PEER
            return self._radio_out.popleft() if self._radio_out else b""

    def _on_datagram(self, data: bytes, sender: Address) -> None:
        """One CRTP packet from the client, off the UDP socket or a memory link (the same bytes)."""
        if not data:
            return
        with self._lock:
            if self.silent or self.shut_down:
                self.dropped += 1
                return
            port = (data[0] & 0xF0) >> 4
            if data[0] != 0xFF and self._drop.get(port, 0) > 0:
                self._drop[port] -= 1
                self.dropped += 1
                return
            self._peer = sender
            if data[0] == 0xFF:  # null packet (cflib's UDP scan, radio keep-alive)
                self._send(PORT_LINK, 3, b"")
                return
            port, channel = (data[0] & 0xF0) >> 4, data[0] & 0x03
            self.received.append((port, channel, data[1:]))
            # a malformed packet is dropped, as the firmware drops short packets
            with contextlib.suppress(struct.error, IndexError):
                self._dispatch(port, channel, data[1:])

    def _dispatch(self, port: int, channel: int, data: bytes) -> None:
        handler = {
            PORT_LINK: self._on_link,
            PORT_PLATFORM: self._on_platform,
            PORT_MEM: self._on_mem,
            PORT_LOG: self._on_log,
            PORT_PARAM: self._on_param,
            PORT_GENERIC: self._on_generic,
            PORT_HL: self._on_hl,
            PORT_SUPERVISOR: self._on_supervisor,
            PORT_COMMANDER: self._on_rpyt,
        }.get(port)
        if handler is not None:
            handler(channel, data)

    def _on_link(self, channel: int, data: bytes) -> None:
        if channel == 0:
            self._send(PORT_LINK, 0, data)  # echo
        elif channel == 1:
            self._send(PORT_LINK, 1, b"Bitcraze Crazyflie".ljust(30, b"\0"))

    def _on_platform(self, channel: int, data: bytes) -> None:
        if channel == 1 and data[0] == 0:
            self._send(PORT_PLATFORM, 1, struct.pack("<Bi", 0, PROTOCOL_VERSION))
        elif channel == 1 and data[0] == 1:
            self._send(PORT_PLATFORM, 1, bytes([1]) + FIRMWARE_VERSION.encode() + b"\0")

    def _on_mem(self, channel: int, data: bytes) -> None:
        if channel == 0 and data[0] == 1:  # CMD_INFO_NBR
            self._send(PORT_MEM, 0, bytes([1, 0]))

    @staticmethod
    def _toc_item(port_cmd: int, ident: int, entry: TocEntry, type_byte: int) -> bytes:
        return (
            struct.pack("<BHB", port_cmd, ident, type_byte)
            + entry.group.encode()
            + b"\0"
            + entry.name.encode()
            + b"\0"
        )

    def _on_log(self, channel: int, data: bytes) -> None:
        if channel == 0:
            if data[0] == 3:  # CMD_GET_INFO_V2
                self._send(
                    PORT_LOG,
                    0,
                    struct.pack("<BHIBB", 3, len(self.log_vars), self.log_crc, LOG_MAX_BLOCKS, LOG_MAX_OPS),
                )
            elif data[0] == 2:  # CMD_GET_ITEM_V2
                ident = struct.unpack_from("<H", data, 1)[0]
                if ident < len(self.log_vars):
                    e = self.log_vars[ident]
                    self._send(PORT_LOG, 0, self._toc_item(2, ident, e, e.type & 0x0F))
                else:
                    self._send(PORT_LOG, 0, bytes([2]))
            return
        if channel != 1:
            return
        cmd = data[0]
        block_id = data[1] if len(data) > 1 else 0
        ret = 8  # ENOEXEC
        block: _Block | None
        if cmd in (6, 7):  # create / append V2
            settings = data[2:]
            ops = [
                (settings[i] & 0x0F, struct.unpack_from("<H", settings, i + 1)[0])
                for i in range(0, len(settings) - 2, 3)
            ]
            if cmd == 6 and block_id in self._blocks:
                ret = 17  # EEXIST
            elif cmd == 7 and block_id not in self._blocks:
                ret = 2  # ENOENT
            elif any(i >= len(self.log_vars) for _, i in ops):
                ret = 2
            else:
                block = self._blocks.setdefault(block_id, _Block())
                size = sum(struct.calcsize(LOG_FORMATS[t]) for t, _ in block.ops + ops)
                if size > 26:
                    ret = 7  # E2BIG
                else:
                    block.ops.extend(ops)
                    ret = 0
        elif cmd in (3, 8):  # start (period in 10 ms) / start V2 (period in ms)
            block = self._blocks.get(block_id)
            if block is None:
                ret = 2
            else:
                period_ms = data[2] * 10 if cmd == 3 else struct.unpack_from("<H", data, 2)[0]
                block.period = max(period_ms, 10) / 1000.0
                block.next_at = self.clock()
                ret = 0
        elif cmd == 4:  # stop
            block = self._blocks.get(block_id)
            ret = 2 if block is None else 0
            if block is not None:
                block.next_at = math.inf
        elif cmd == 2:  # delete
            ret = 0 if self._blocks.pop(block_id, None) is not None else 2
        elif cmd == 5:  # reset
            self._blocks.clear()
            ret = 0
        self._send(PORT_LOG, 1, bytes([cmd, block_id, ret]))

    def _on_param(self, channel: int, data: bytes) -> None:
        if channel == 0:
            if data[0] == 3:
                self._send(PORT_PARAM, 0, struct.pack("<BHI", 3, len(self.param_vars), self.param_crc))
            elif data[0] == 2:
                ident = struct.unpack_from("<H", data, 1)[0]
                if ident < len(self.param_vars):
                    e = self.param_vars[ident]
                    self._send(PORT_PARAM, 0, self._toc_item(2, ident, e, e.type & 0xFF))
                else:
                    self._send(PORT_PARAM, 0, bytes([2]))
            return
        ident = struct.unpack_from("<H", data, 0)[0]
        if ident >= len(self.param_vars):
            self._send(PORT_PARAM, channel, data[:2] + bytes([2]))  # ENOENT / PARAM_NOT_FOUND
            return
        e = self.param_vars[ident]
        fmt = PARAM_FORMATS[e.type & 0x0F]
        full = f"{e.group}.{e.name}"
        if channel == 1:  # read
            self._send(PORT_PARAM, 1, data[:2] + b"\0" + struct.pack(fmt, self.params[full]))
        elif channel == 2:  # write
            self.params[full] = struct.unpack_from(fmt, data, 2)[0]
            self._send(PORT_PARAM, 2, data)
            if full == "stabilizer.stop" and self.params[full]:
                self._emergency_stop()

    def _on_generic(self, channel: int, data: bytes) -> None:
        now = self.clock()
        if channel == 1:
            if data[0] == 0:  # notify setpoint stop (crtp_commander.c): commanderRelaxPriority only
                self.notify_stops += 1
                self._streaming = False
                if self._traj is None and self.motors:
                    # the planner was stopped by the stream: its null set-point stops the motors
                    # until a high-level command comes (crtp_commander_high_level.c)
                    self._motors_off(now)
            return
        kind = data[0]
        self.setpoints += 1
        if kind == 0:  # TYPE_STOP: motors off
            self._motors_off(now)
            return
        if kind not in (8, 10):
            return
        values = struct.unpack_from("<ffff", data, 1)
        if not all(math.isfinite(v) for v in values):
            return
        if not self.armed or self.locked:
            return
        self._streaming = True
        self._traj = None  # commander.c: a higher-priority set-point stops the high-level planner
        self._sp_kind = "world" if kind == 8 else "hover"
        self._sp = values
        self._sp_at = now
        self.motors = True
        self._landed_at = None

    def _on_rpyt(self, channel: int, data: bytes) -> None:
        _roll, _pitch, _yaw_rate, thrust = struct.unpack_from("<fffH", data, 0)
        self.setpoints += 1
        if thrust == 0 and self.motors:
            self._motors_off(self.clock())

    def _can_fly(self) -> bool:
        """supervisor.c supervisorCanFly: armed and neither locked nor crashed."""
        return self.armed and not self.locked and not self.crashed

    def _on_hl(self, channel: int, data: bytes) -> None:
        cmd = data[0]
        name, ret = self._hl_command(cmd, data, self.clock())
        self.hl_answers.append((name, ret))
        # crtp_commander_high_level.c crtpCommanderHighLevelTask: every packet answered, 4 bytes
        self._send(PORT_HL, channel, bytes([cmd]) + data[1:3].ljust(2, b"\0") + bytes([ret]))

    def _hl_command(self, cmd: int, data: bytes, now: float) -> tuple[str, int]:
        """One high-level command: its name and the result the firmware answers."""
        if cmd == 7 or cmd == 8:  # takeoff2 / land2: group, height, yaw, use current yaw, duration
            name = "takeoff" if cmd == 7 else "land"
            _, height, yaw, use_current, duration = struct.unpack_from("<BffBf", data, 1)
            self.hl_commands.append((name, (height, duration)))
            if not self._can_fly():
                return name, HL_EBUSY  # stabilizer.c crtpCommanderBlock(!canFly)
            if cmd == 7 and self._traj is not None:
                return name, HL_REFUSED  # planner.c plan_takeoff: only from an idle planner
            if cmd == 8 and self._traj is not None and self._traj.kind == "land":
                return name, HL_REFUSED  # planner.c plan_land: not while landing
            if cmd == 8 and not self.motors and self.z <= 0.0:
                return name, HL_OK  # a landing on the floor: nothing moves
            target_yaw = self.yaw if use_current else math.degrees(yaw)
            self._start(now, name, (self.x, self.y, height, target_yaw), duration)
            return name, HL_OK
        if cmd in (4, 12):  # go_to / go_to2: group, relative, [linear], x, y, z, yaw (rad), duration
            if cmd == 4:
                _, relative, x, y, z, yaw, duration = struct.unpack_from("<BBfffff", data, 1)
            else:
                _, relative, _linear, x, y, z, yaw, duration = struct.unpack_from("<BBBfffff", data, 1)
            self.hl_commands.append(("goto", (x, y, z, math.degrees(yaw), duration, relative)))
            if not self._can_fly():
                return "goto", HL_EBUSY
            if not self.motors and self.z <= 0.0:
                return "goto", HL_OK  # on the floor (not modelled: a go_to that lifts off)
            if relative:  # from the planner's current goal, or the state when it is idle
                base = self._traj.end if self._traj is not None and self._traj.kind == "hold" else None
                bx, by, bz, byaw = base or (self.x, self.y, self.z, self.yaw)
                x, y, z, yaw_deg = bx + x, by + y, bz + z, byaw + math.degrees(yaw)
            else:
                yaw_deg = math.degrees(yaw)
            self._start(now, "goto", (x, y, z, yaw_deg), duration)
            return "goto", HL_OK
        if cmd == 3:  # stop: planner idle -> the null set-point, motors off
            self.hl_commands.append(("stop", ()))
            self._traj = None
            if not self._streaming and self.motors:
                self._motors_off(now)
            return "stop", HL_OK
        if cmd == 0:  # set group mask
            return "group", HL_OK
        return f"cmd{cmd}", HL_ENOEXEC

    def _on_supervisor(self, channel: int, data: bytes) -> None:
        cmd = data[0]
        if channel == 0 and cmd == 0x0C:
            self._send(PORT_SUPERVISOR, 0, struct.pack("<BH", 0x80 | cmd, self.supervisor_info()))
        elif channel == 1 and cmd == 0x01:
            do_arm = bool(data[1])
            success = True
            if do_arm != self.armed:
                if do_arm and (self.locked or self.crashed):
                    success = False
                elif not do_arm and self.flying:
                    self._motors_off(self.clock())
                    self._disarm()
                elif do_arm:
                    self.armed = True
                else:
                    self._disarm()
            self._send(PORT_SUPERVISOR, 1, bytes([0x80 | cmd, int(success), int(self.armed)]))
        elif channel == 1 and cmd == 0x03:
            self._emergency_stop()

    # ------------------------------------------------------------------ vehicle
    def _disarm(self) -> None:
        self.armed = False
        self._disarmed_at = self.clock()

    def _emergency_stop(self) -> None:
        self.emergency_stops += 1
        self._motors_off(self.clock())
        self.locked = True
        self._disarm()

    def _motors_off(self, now: float) -> None:
        """Motors stopped: a Crazyflie in the air falls (`_step`), on the floor it just stops."""
        self.motors = False
        self._streaming = False
        self._traj = None
        self.vx = self.vy = 0.0
        self._landed_at = now

    def _start(self, now: float, kind: str, end: tuple[float, float, float, float], duration: float) -> None:
        duration = max(duration, 0.05)
        yaw_end = self.yaw + ((end[3] - self.yaw + 180.0) % 360.0 - 180.0)
        self._traj = _Trajectory(
            kind, (self.x, self.y, self.z, self.yaw), (end[0], end[1], end[2], yaw_end), now, duration
        )
        self._traj_finished = False
        if not self._streaming:
            self.motors = True
            self.vz = 0.0  # a fall caught by the planner
            self._landed_at = None

    def _track_battery(self, now: float) -> None:
        """pm_stm32f4.c pmTask: the low and critical timers restart while above their voltages."""
        if self.vbat >= LOW_VOLTAGE:
            self._low_since = math.inf
        elif math.isinf(self._low_since):
            self._low_since = now
        if self.vbat >= CRITICAL_LOW_VOLTAGE:
            self._critical_since = math.inf
        elif math.isinf(self._critical_since):
            self._critical_since = now
        if (
            self.auto_shutdown
            and not self.shut_down
            and self.pm_state == PM_LOW_POWER
            and now - self._critical_since > LOW_DURATION
        ):
            self.shut_down = True  # pmSystemShutdown: the nRF powers everything off
            self._motors_off(now)
            self._disarm()

    def _step(self, dt: float, now: float) -> None:
        if self.motors and self.drain > 0:
            self.vbat = max(self.vbat - self.drain * dt, 2.5)
        self._track_battery(now)
        if self.motors:
            self._thrust_at = now
        if not self.motors:
            if self.z > 0.0:  # falling
                self.vz -= GRAVITY * dt
                self.z = max(self.z + self.vz * dt, 0.0)
                if self.z == 0.0:
                    self.vz = 0.0
                    self.falls += 1
            self._supervise_ground(now)
            return
        if self._streaming:
            age = now - self._sp_at
            if age > WDT_SHUTDOWN:
                self._motors_off(now)
                self.locked = True  # supervisor: ExceptFreeFall -> Locked
                self._disarm()
                return
            a = 1.0 - math.exp(-dt / self.velocity_tau)
            if age > WDT_STABILIZE:
                # WarningLevelOut (supervisorOverrideSetpoint): roll/pitch level, yaw rate 0, z as set
                # -- the horizontal velocity coasts, the vertical one is still flown
                tx, ty, rate = self.vx, self.vy, 0.0
                if self._sp_kind == "world":
                    tz = self._sp[2]
                else:
                    tz = max(min((self._sp[3] - self.z) * 2.0, 1.0), -1.0)
            elif self._sp_kind == "world":
                tx, ty, tz, rate = self._sp
            else:  # hover: body-frame vx, vy, yaw rate, absolute height
                bvx, bvy, rate, height = self._sp
                c, s = math.cos(math.radians(self.yaw)), math.sin(math.radians(self.yaw))
                tx, ty = bvx * c - bvy * s, bvx * s + bvy * c
                tz = max(min((height - self.z) * 2.0, 1.0), -1.0)
            self.vx += (tx - self.vx) * a
            self.vy += (ty - self.vy) * a
            self.vz += (tz - self.vz) * a
            self.x += self.vx * dt
            self.y += self.vy * dt
            self.z = max(self.z + self.vz * dt, 0.0)
            self.yaw = (self.yaw + rate * dt + 180.0) % 360.0 - 180.0
            return
        traj = self._traj
        if traj is None:  # the planner idle and nothing streamed: the null set-point
            self._motors_off(now)
            return
        s = (now - traj.t0) / traj.duration
        p, v = _minimum_jerk(s)
        coords = [a0 + (a1 - a0) * p for a0, a1 in zip(traj.start, traj.end, strict=True)]
        self.vx, self.vy, self.vz = (
            (a1 - a0) * v / traj.duration for a0, a1 in zip(traj.start[:3], traj.end[:3], strict=True)
        )
        self.x, self.y, self.z = coords[0], coords[1], max(coords[2], 0.0)
        self.yaw = (coords[3] + 180.0) % 360.0 - 180.0
        if s >= 1.0:
            self.vx = self.vy = self.vz = 0.0
            self._traj_finished = True
            if traj.kind == "land":
                self._motors_off(now)  # planner.c: a finished landing leaves the planner idle
            else:
                # the planner holds the end pose until the next command
                self._traj = _Trajectory("hold", traj.end, traj.end, now, 1.0)

    def _supervise_ground(self, now: float) -> None:
        """supervisor.c: landed for landed_timeout -> disarm; auto-arming re-arms (motors off)."""
        landed = self._landed_at is not None and self.z <= 0.0
        # Landed is entered once the flying bit drops (its hysteresis), the timeout counts from there
        since = max(self._landed_at or now, self._thrust_at + FLYING_HYSTERESIS)
        if self.armed and landed and now - since >= self.landed_timeout:
            self._disarm()  # Landed -> Reset
            self._landed_at = None
        if (
            not self.armed
            and self.auto_arming
            and not (self.locked or self.crashed or self.shut_down)
            and now - self._disarmed_at >= self.rearm_delay
        ):
            self.armed = True  # PreFlChecksPassed -> supervisorRequestArming(true) (AUTO_ARMING)

    def _sim_loop(self) -> None:
        last = self.clock()
        while not self._workers.stop.wait(0.01):
            now = self.clock()
            with self._lock:
                self._step(now - last, now)
                self._stream_logs(now)
            last = now

    def _stream_logs(self, now: float) -> None:
        stamp = int((now - self._boot) * 1000) & 0xFFFFFF
        for block_id, block in self._blocks.items():
            if now < block.next_at:
                continue
            block.next_at = max(block.next_at + block.period, now)
            payload = bytes([block_id]) + stamp.to_bytes(3, "little")
            for fetch_type, index in block.ops:
                e = self.log_vars[index]
                value = self.log_value(f"{e.group}.{e.name}")
                fmt = LOG_FORMATS[fetch_type]
                payload += struct.pack(fmt, value if fmt in ("<f", "<e") else int(value))
            self._send(PORT_LOG, 2, payload)
