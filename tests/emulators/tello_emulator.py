"""A DJI Tello (SDK 2.0 text protocol) emulator, so tests can drive the real djitellopy client.

Protocol (what the real Tello does, and so what this emulates):

* Commands are UDP text datagrams to port 8889. Replies go back *from the address the emulator is bound
  to* to the sender's address: djitellopy files replies by the sender's IP, so an emulator bound to
  ``0.0.0.0`` answering from another address would be ignored by it.
* ``command`` enters SDK mode; from then on a state line is sent at ``state_rate`` (10 Hz) to the IP that
  sent ``command``, port 8890 (``state_port``), or to ``state_target`` when given::

      mid:-1;x:0;y:0;z:0;mpry:0,0,0;pitch:0;roll:0;yaw:0;vgx:0;vgy:0;vgz:0;templ:60;temph:62;tof:10;
      h:0;bat:100;baro:100.00;time:0;agx:0.00;agy:0.00;agz:-1000.00;\\r\\n

  (one line; the ``mid..mpry`` mission-pad block is dropped with ``mission_pad_fields=False``, as on a
  non-EDU Tello). Before SDK mode other commands are answered ``error`` (an emulator choice; ``rc`` and
  ``emergency`` never get a reply).
* **Command spacing** (djitellopy ``Tello.TIME_BTW_COMMANDS`` = 0.1 s, whose comment says "Commands
  very consecutive makes the drone not respond to them", and ``TIME_BTW_RC_CONTROL_COMMANDS`` = 0.001 s
  for ``rc``): a datagram other than ``rc`` that arrives less than ``command_spacing`` (0.1 s) after
  the last one the Tello took is **ignored**. Measured from the last command, not from the last reply:
  djitellopy 2.5.0 means to wait 0.1 s after the answer, but ``send_command_with_return`` sleeps
  ``diff`` instead of ``TIME_BTW_COMMANDS - diff`` and notices the answer only at its next 0.1 s poll,
  so what it usually gives (and real Tellos answer) is 0.1 s between two commands, with the next one
  sometimes a few ms after the previous answer. Not always: when the answer is already there at its
  first look (it checks before its first 0.1 s sleep), the next command goes at once -- against this
  emulator, which answers within a millisecond, a loaded machine that delays djitellopy's thread after
  its send does that (measured: ``sdk?`` then ``battery?`` 1 ms apart). A command too close is not carried out, never answered
  (`ignored` keeps it; DJITelloPy issue #43 is where 0.1 s was settled on, from use, since neither the
  SDK guides nor DJI's own samples give a figure: the worst case an adapter must survive). ``emergency`` is no exception (djitellopy's ``send_command_without_return``
  carries the same comment); ``rc`` is.
* ``takeoff`` climbs to ``takeoff_height`` (0.8 m) in ``takeoff_time`` (2.5 s), then hovers there
  ``takeoff_settle`` s more (0 by default) before it answers ``ok``: a real Tello orients itself with
  its camera and sensors first, and its ``ok`` has been reported more than 7 s after the command
  (DJITelloPy issue #31, which raised djitellopy's ``TAKEOFF_TIMEOUT`` to 20 s; its
  ``RESPONSE_TIMEOUT`` for other commands is 7 s). Until the ``ok`` the take-off is the running
  manoeuvre: other motion commands get ``error`` and ``rc`` is not flown; ``land`` descends at ``land_speed`` and answers when down. ``up/down/left/right/forward/back
  x`` (20..500 cm) fly at the ``speed`` setting and ``go x y z speed`` (body frame: x forward, y left,
  z up, cm; 10..100 cm/s) at its own speed, answering when done; out-of-range values get ``out of
  range``, motion on the ground ``error Motor stop``, unknown words ``unknown command: WORD``; ``cw/ccw x`` turn at ``rotate_rate``. While one of these is
  running other motion commands get ``error``; ``stop`` cancels it (the cancelled command is never
  answered) and answers ``ok``. ``emergency`` stops the motors (the drone drops to the ground) and, like
  ``rc``, gets **no reply**: the SDK 2.0 user guide lists "ok / error" for it, but real units do not
  answer (DJITelloPy issue #125, a Tello on firmware 01.04.92.01; dji-sdk/Tello-Python issue #85, a
  Tello EDU, which DJI's support called a known issue), so djitellopy 2.5's ``Tello.emergency`` sends
  it with ``send_command_without_return``, as ``send_rc_control`` sends ``rc``; a reply would be
  taken as the answer to the next command.
* ``rc a b c d``: stick values -100..100 for left/right, forward/back, up/down, yaw, held until the next
  ``rc``. Full stick (100) is ``max_speed`` m/s horizontally, ``max_vertical_speed`` m/s vertically and
  ``max_yaw_rate`` deg/s; values scale linearly, and the velocity follows with a first-order lag of
  ``response_tau`` s. rc only acts while flying and no manoeuvre runs.
* Read commands: ``speed?`` (cm/s), ``battery?`` (%), ``height?`` (``"8dm"``: decimetres with a unit,
  as real firmware answers), ``time?`` (``"12s"``, motor time), ``wifi?``, ``sdk?``, ``sn?``,
  ``tof?`` (``"810mm"``), ``baro?``, ``temp?`` (``"60~62C"``), ``attitude?``.
* Safety behaviour: a flying Tello lands itself when no command has arrived for ``auto_land_timeout``
  (15 s; counted from the end of the last manoeuvre); it also lands at ``auto_land_battery`` percent
  and refuses ``takeoff`` below ``min_takeoff_battery``.

Frames and units of the emulated state (documented because the SDK guide leaves them open):

* Position ``x, y, z`` (m, in ``snapshot()``): a ground frame fixed at power-on, x along the heading the
  Tello had at power-on (yaw 0), y 90 degrees clockwise from it (to the right), z up = height above
  the take-off point. ``yaw`` is degrees, clockwise positive, in (-180, 180], 0 at power-on.
* State line: ``vgx, vgy`` are that ground frame's x and y velocities and ``vgz`` the vertical velocity
  *positive down*, all in **dm/s** (integer decimetres per second). The SDK 2.0/3.0 guides name the
  fields ("vgx: x-axis speed") without a unit, and djitellopy's ``get_speed_x`` says only "int:
  speed"; dm/s is the community's reading. ``velocity_scale`` (10: state units per m/s) sets
  another (100 = cm/s), so a test can show what an adapter does when the assumption is wrong;
  ``h`` is the height in cm with the Tello's decimetre resolution; ``tof`` is cm from the ground (10
  when landed); ``baro`` is metres (arbitrary datum; the SDK 2.0 guide: "baro? get barometer value (m)",
  a ``%.2f`` in the state line, although djitellopy's ``get_barometer`` docstring says cm);
  ``agx/agy/agz`` are 0.001 g; ``pitch/roll`` are a
  cosmetic tilt that follows the horizontal velocity. The community has reported inconsistent signs of
  ``vgx/vgy`` on real units; adapters should keep the sign convention configurable.

Faults and dynamics for tests (all settable while running):

* ``stop_state()`` / ``resume_state()``: state packets stop (only the state port is lost).
* ``silence(seconds)``: the Wi-Fi link is down both ways for that long: datagrams to the Tello are
  lost (they do not count as commands for the 15 s auto-landing), and no reply or state comes back.
  With ``forget_sdk_on_silence = True`` the Tello has left SDK mode when the link returns (as after a
  reboot) and sends state again only after a new ``command``.
* ``lose_reply(command, count=1)``: the next `count` answers to `command` (``"takeoff"``, ``"land"``,
  ...) are lost on the way back; the command itself is carried out.
* ``mute_replies = True`` (every command executed, none answered), ``refuse_takeoff = True``
  (``takeoff`` answers ``error``), ``set_battery(pct)``.
* ``vertical_tau``: the time constant of the vertical response to ``rc`` (s; default
  ``response_tau``): 0.15 s is a brisk Tello, 0.6 s a sluggish one.
* ``height_resolution_cm`` (10: the Tello reports ``h`` in whole decimetres, as cm) and
  ``height_rounding`` (``"round"`` to the nearest step, or ``"floor"``).
* ``auto_land_timeout``: the Tello lands itself this long after the last command it received, counted
  from the end of the command it was executing (15 s: SDK 3.0 user guide, "Safety Function").

Running it next to djitellopy: djitellopy binds 8889/8890 on all addresses once per process, so the
emulator cannot bind 8889 in the same network namespace. Use :class:`tests.harness.netns.NetnsPair`
(two namespaces joined by a veth pair) and hand the emulator a socket made in the drone-side namespace
(``TelloEmulator(sock=net.udp_socket("a", (net.addr_a, 8889)))``), or run this module's CLI there::

    python -m tests.emulators.tello_emulator --host 192.168.10.1 [--auto-land-timeout 15] ...

The CLI prints ``READY <host> <port>`` once bound and a JSON snapshot of the final state on exit
(SIGTERM/SIGINT). For protocol-only tests, any address/port on 127.0.0.0/8 works with a plain socket.
"""

from __future__ import annotations

import argparse
import contextlib
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
from collections.abc import Callable
from dataclasses import asdict, dataclass

from antalate_lcm.vehicles.tello.link import MemoryLink
from tests.emulators.lifecycle import Emulator, Motion

LOG = logging.getLogger("antalate.tests.tello_emulator")

Address = tuple[str, int]
_MEMORY_SENDER: Address = ("memory", 8889)  # where commands off a memory link come from
#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; Python's socket module does not name it): the kernel stamps
#: each datagram on arrival, so the command spacing is measured between arrivals, as a Tello hears them,
#: not between the moments a loaded test machine got round to reading them (two commands 0.1 s apart,
#: the first read late, looked 50 ms apart and the second was wrongly ignored)
_SO_TIMESTAMPNS = 35


def _stamp_arrivals(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):  # not Linux: spacing from the moment a datagram is read
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)


def _arrival(ancillary: list[tuple[int, int, bytes]]) -> float | None:
    """A datagram's kernel arrival time on `time.monotonic`'s clock (None: not stamped)."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= 16:
            sec, nsec = struct.unpack("qq", data[:16])
            stamped: float = sec + nsec * 1e-9
            return time.monotonic() - max(0.0, time.time() - stamped)
    return None


@dataclass(frozen=True)
class TelloCommand:
    """One datagram the emulator received (kept for assertions)."""

    t: float  # time.monotonic() at reception
    text: str
    sender: Address


@dataclass(frozen=True)
class TelloSnapshot(Motion):
    """A consistent copy of the emulated drone's state (frames: see the module docstring; vz up positive)."""

    flying: bool
    sdk_mode: bool
    stream_on: bool
    battery: float
    rc: tuple[int, int, int, int]
    maneuver: str | None
    client: Address | None
    state_packets: int
    motor_time: float
    speed_setting: int  # cm/s


@dataclass
class _Maneuver:
    """A blocking command in progress: fly to ``target`` / turn to ``yaw``, then answer ``ok``."""

    name: str
    target: tuple[float, float, float]
    speed: float  # m/s along the straight line
    yaw: float | None = None  # unwrapped target yaw, degrees
    yaw_rate: float = 90.0
    reply_to: Address | None = None
    lands: bool = False
    hold_until: float = 0.0  # monotonic time before which it is not done (flip)
    settle: float = 0.0  # s it stays at the target before it is done (a take-off orienting itself)
    reached_at: float | None = None  # when it got to the target


def _wrap180(deg: float) -> float:
    """Degrees into (-180, 180], the range the Tello reports yaw in."""
    wrapped = math.fmod(deg + 180.0, 360.0)
    if wrapped <= 0:
        wrapped += 360.0
    return wrapped - 180.0


def _move_handler(name: str) -> Callable[[TelloEmulator, list[str], Address, float], str | None]:
    """The handler of one motion command (``up``, ``forward``…): all share ``_cmd_move``."""

    def handle(emu: TelloEmulator, args: list[str], sender: Address, now: float) -> str | None:
        return emu._cmd_move(name, args, sender)

    return handle


class TelloEmulator(Emulator["TelloSnapshot"]):
    """An emulated Tello on one UDP socket; ``start()``/``stop()`` or ``with``. All methods are thread-safe."""

    MOTION_COMMANDS = ("up", "down", "left", "right", "forward", "back")

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8889,
        *,
        sock: socket.socket | None = None,
        state_port: int = 8890,
        state_target: Address | None = None,
        state_rate: float = 10.0,
        tick_rate: float = 50.0,
        max_speed: float = 1.0,
        max_vertical_speed: float = 1.0,
        max_yaw_rate: float = 100.0,
        response_tau: float = 0.2,
        takeoff_height: float = 0.8,
        takeoff_time: float = 2.5,
        land_speed: float = 0.6,
        rotate_rate: float = 90.0,
        flip_time: float = 1.0,
        auto_land_timeout: float = 15.0,
        battery: float = 100.0,
        battery_drain: float = 0.1,
        min_takeoff_battery: float = 10.0,
        auto_land_battery: float = 5.0,
        serial: str = "0TQZK7EMU0001",
        sdk_version: str = "20",
        wifi_snr: int = 90,
        mission_pad_fields: bool = True,
        vertical_tau: float | None = None,
        height_resolution_cm: int = 10,
        height_rounding: str = "round",
        memory: bool = False,
        command_spacing: float = 0.1,
        takeoff_settle: float = 0.0,
        velocity_scale: float = 10.0,
    ) -> None:
        """Bind ``host:port`` (``port=0``: a free port) or adopt ``sock`` (already bound, e.g. in a netns).

        With `memory` the emulator binds nothing: its datagrams go over `link`, a `MemoryLink` for
        ``TelloAdapter(params, link=lambda _p: emu.link)`` (commands in; replies and state lines out).

        Speeds are m/s and deg/s, times seconds, battery percent; ``battery_drain`` is %/s in flight.
        """
        super().__init__()
        self._host, self._port = host, port
        self._sock = sock
        self.link: MemoryLink | None = None
        if memory:
            self._host, self._port = _MEMORY_SENDER
            self.link = MemoryLink(self._from_link, name="tello-emulator")
        self.state_port = state_port
        self.state_target = state_target
        self.state_rate = state_rate
        self.tick_rate = tick_rate
        self.max_speed = max_speed
        self.max_vertical_speed = max_vertical_speed
        self.max_yaw_rate = max_yaw_rate
        self.response_tau = response_tau
        self.takeoff_height = takeoff_height
        self.takeoff_time = takeoff_time
        self.land_speed = land_speed
        self.rotate_rate = rotate_rate
        self.flip_time = flip_time
        self.auto_land_timeout = auto_land_timeout
        self.battery_drain = battery_drain
        self.min_takeoff_battery = min_takeoff_battery
        self.auto_land_battery = auto_land_battery
        self.serial = serial
        self.sdk_version = sdk_version
        self.wifi_snr = wifi_snr
        self.mission_pad_fields = mission_pad_fields
        self.vertical_tau = vertical_tau
        self.height_resolution_cm = height_resolution_cm
        if height_rounding not in ("round", "floor"):
            raise ValueError(f"height_rounding must be 'round' or 'floor', got {height_rounding!r}")
        self.height_rounding = height_rounding
        self.command_spacing = command_spacing  # s: closer non-rc datagrams are ignored (djitellopy)
        self.takeoff_settle = takeoff_settle  # s hovering at the take-off height before "ok"
        self.velocity_scale = velocity_scale  # state-line units per m/s of vgx/vgy/vgz (10: dm/s)

        # Fault switches: plain attributes so a test can flip them at any time.
        self.refuse_takeoff = False
        self.mute_replies = False
        self.forget_sdk_on_silence = False
        self._lose: dict[str, int] = {}
        self._silent_until = -math.inf
        self._silence_pending_reset = False
        self._lost_replies: list[tuple[str, str]] = []

        self._lock = threading.RLock()
        self._state_enabled = True
        self._x = self._y = self._z = 0.0
        self._vx = self._vy = self._vz = 0.0
        self._yaw = 0.0  # unwrapped, degrees
        self._flying = False
        self._sdk_mode = False
        self._stream_on = False
        self._battery = float(battery)
        self._motor_time = 0.0
        self._speed_setting = 100
        self._rc = (0, 0, 0, 0)
        self._maneuver: _Maneuver | None = None
        self._client: Address | None = None
        self._last_command = time.monotonic()
        self._state_packets = 0
        self._commands: list[TelloCommand] = []
        self._replies: list[tuple[str, Address]] = []
        self._ignored: list[TelloCommand] = []
        self._busy_until = -math.inf  # monotonic time before which a non-rc datagram is ignored

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self) -> TelloEmulator:
        if self._workers.running:
            return self
        if self._sock is None and self.link is None:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.bind((self._host, self._port))
            except OSError:
                sock.close()
                raise
            self._sock = sock
        if self._sock is not None:
            self._host, self._port = self._sock.getsockname()[:2]
        self._workers.start((self._run, f"tello-emu-{self._port}"))
        LOG.info("Tello emulator on %s:%d", self._host, self._port)
        return self

    def _close_transports(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    @property
    def address(self) -> Address:
        """Where the emulator listens (the real port after ``start()`` when 0 was asked for)."""
        return (self._host, self._port)

    # -- observation -----------------------------------------------------------------------------

    def snapshot(self) -> TelloSnapshot:
        with self._lock:
            return TelloSnapshot(
                x=self._x,
                y=self._y,
                z=self._z,
                yaw=_wrap180(self._yaw),
                vx=self._vx,
                vy=self._vy,
                vz=self._vz,
                flying=self._flying,
                sdk_mode=self._sdk_mode,
                stream_on=self._stream_on,
                battery=self._battery,
                rc=self._rc,
                maneuver=self._maneuver.name if self._maneuver else None,
                client=self._client,
                state_packets=self._state_packets,
                motor_time=self._motor_time,
                speed_setting=self._speed_setting,
            )

    @property
    def commands(self) -> list[TelloCommand]:
        """Every datagram received so far, oldest first (a copy)."""
        with self._lock:
            return list(self._commands)

    @property
    def replies(self) -> list[tuple[str, Address]]:
        """Every reply sent so far with its destination (a copy)."""
        with self._lock:
            return list(self._replies)

    @property
    def ignored(self) -> list[TelloCommand]:
        """Datagrams ignored because they came within ``command_spacing`` (oldest first, a copy)."""
        with self._lock:
            return list(self._ignored)

    def command_texts(self) -> list[str]:
        return [c.text for c in self.commands]

    # -- fault injection -------------------------------------------------------------------------

    def stop_state(self) -> None:
        """Stop sending state packets (what a lost Wi-Fi link looks like to djitellopy)."""
        with self._lock:
            self._state_enabled = False

    def resume_state(self) -> None:
        with self._lock:
            self._state_enabled = True

    def silence(self, seconds: float) -> None:
        """The link is down both ways for `seconds` (see the module docstring)."""
        with self._lock:
            self._silent_until = time.monotonic() + seconds
            self._silence_pending_reset = self.forget_sdk_on_silence

    def silent(self) -> bool:
        with self._lock:
            return time.monotonic() < self._silent_until

    def lose_reply(self, command: str, count: int = 1) -> None:
        """Lose the next `count` answers to `command` (the command is still carried out)."""
        with self._lock:
            self._lose[command] = self._lose.get(command, 0) + count

    @property
    def lost_replies(self) -> list[tuple[str, str]]:
        """(command, answer) of every reply lost on purpose so far."""
        with self._lock:
            return list(self._lost_replies)

    def height_cm(self) -> int:
        """The state's ``h``: cm, in steps of ``height_resolution_cm``."""
        with self._lock:
            step = max(1, int(self.height_resolution_cm))
            cm = self._z * 100.0
            steps = math.floor(cm / step + 1e-9) if self.height_rounding == "floor" else round(cm / step)
            return int(steps * step)

    def set_battery(self, pct: float) -> None:
        """Set the battery level; at or below ``auto_land_battery`` a flying Tello lands itself."""
        with self._lock:
            self._battery = max(0.0, min(100.0, float(pct)))

    # -- the state line --------------------------------------------------------------------------

    def state_line(self) -> str:
        """The state datagram as the Tello formats it (see the module docstring for units)."""
        with self._lock:
            yaw_rad = math.radians(self._yaw)
            fwd = self._vx * math.cos(yaw_rad) + self._vy * math.sin(yaw_rad)
            right = -self._vx * math.sin(yaw_rad) + self._vy * math.cos(yaw_rad)
            pitch = round(-10.0 * fwd)
            roll = round(10.0 * right)
            templ = int(min(90.0, 60.0 + self._motor_time / 20.0))
            fields = [
                f"pitch:{pitch}",
                f"roll:{roll}",
                f"yaw:{round(_wrap180(self._yaw))}",
                f"vgx:{round(self._vx * self.velocity_scale)}",
                f"vgy:{round(self._vy * self.velocity_scale)}",
                f"vgz:{round(-self._vz * self.velocity_scale)}",
                f"templ:{templ}",
                f"temph:{templ + 2}",
                f"tof:{round(self._z * 100) + 10}",
                f"h:{self.height_cm()}",
                f"bat:{int(self._battery)}",
                f"baro:{100.0 + self._z:.2f}",
                f"time:{int(self._motor_time)}",
                f"agx:{round(-1000.0 * math.sin(math.radians(pitch)), 2) + 0.0:.2f}",
                f"agy:{round(1000.0 * math.sin(math.radians(roll)), 2) + 0.0:.2f}",
                "agz:-1000.00",
            ]
        prefix = "mid:-1;x:0;y:0;z:0;mpry:0,0,0;" if self.mission_pad_fields else ""
        return prefix + ";".join(fields) + ";\r\n"

    # -- the I/O + physics thread ----------------------------------------------------------------

    def _run(self) -> None:
        sock = self._sock
        if sock is not None:
            _stamp_arrivals(sock)
        tick = 1.0 / self.tick_rate
        state_period = 1.0 / self.state_rate
        last = time.monotonic()
        next_tick = last + tick
        next_state = last
        while not self._workers.stop.is_set():
            wait = max(0.0, min(next_tick - time.monotonic(), 0.05))
            if sock is None:  # a memory link delivers on the sender's thread (_from_link)
                self._workers.stop.wait(wait)
                ready: list[socket.socket] = []
            else:
                try:
                    ready, _, _ = select.select([sock], [], [], wait)
                except (OSError, ValueError):
                    break  # socket closed under us: stop() is in progress
            if ready and sock is not None:
                try:
                    data, ancillary, _, sender = sock.recvmsg(4096, 64)
                except OSError:
                    data = b""
                if data:
                    self._on_datagram(data, sender, _arrival(ancillary))
            now = time.monotonic()
            if now >= next_tick:
                self._step(now - last, now)
                last = now
                next_tick = now + tick
            if now >= next_state:
                next_state = now + state_period
                self._send_state()

    def _from_link(self, text: str) -> None:
        """A command off the memory link: the same datagram a socket would have delivered."""
        self._on_datagram(text.encode("utf-8"), _MEMORY_SENDER)

    def _send(self, payload: bytes, dest: Address) -> None:
        if self.link is not None:
            if dest[1] == self.state_port:
                self.link.push_state(payload.decode("ascii"))
            else:
                self.link.reply(payload.decode("utf-8"))
            return
        if self._sock is None:
            return
        try:
            self._sock.sendto(payload, dest)
        except OSError as exc:  # unreachable peer etc.: a real Tello does not care either
            LOG.debug("send to %s failed: %s", dest, exc)

    def _reply(self, text: str, dest: Address, command: str = "") -> None:
        with self._lock:
            if self.mute_replies or time.monotonic() < self._silent_until:
                return
            if self._lose.get(command, 0) > 0:
                self._lose[command] -= 1
                self._lost_replies.append((command, text))
                return
            self._replies.append((text, dest))
        self._send(text.encode("utf-8"), dest)

    def _send_state(self) -> None:
        with self._lock:
            if time.monotonic() < self._silent_until:
                return
            if self._silence_pending_reset:
                self._silence_pending_reset = False
                self._sdk_mode = False  # came back as after a reboot: state only after "command"
            if not (self._sdk_mode and self._state_enabled):
                return
            dest = self.state_target
            if dest is None:
                if self._client is None:
                    return
                dest = (self._client[0], self.state_port)
            self._state_packets += 1
        self._send(self.state_line().encode("ascii"), dest)

    # -- command handling ------------------------------------------------------------------------

    def _on_datagram(self, data: bytes, sender: Address, arrived: float | None = None) -> None:
        try:
            text = data.decode("utf-8").strip()
        except UnicodeDecodeError:
            self._reply("error", sender)
            return
        now = time.monotonic() if arrived is None else arrived
        with self._lock:
            if now < self._silent_until:
                return  # lost on the way: not a command the Tello heard
            if text.split()[:1] != ["rc"]:
                if now < self._busy_until:  # too soon after the last command or reply: not heard
                    self._ignored.append(TelloCommand(now, text, sender))
                    return
                self._busy_until = now + self.command_spacing
            self._commands.append(TelloCommand(now, text, sender))
            self._last_command = now
            reply = self._handle(text, sender, now)
        if reply is not None:
            self._reply(reply, sender, text.split()[0] if text.split() else "")

    def _handle(self, text: str, sender: Address, now: float) -> str | None:
        """Apply one command (lock held); the immediate reply, or None (no reply, or a deferred one)."""
        words = text.split()
        if not words:
            return "error"
        cmd, args = words[0], words[1:]
        if cmd == "command":
            self._sdk_mode = True
            self._client = sender
            return "ok"
        if not self._sdk_mode:
            return None if cmd in ("rc", "emergency") else "error"
        if cmd == "rc":
            self._on_rc(args)
            return None
        if cmd == "emergency":
            self._maneuver = None
            self._flying = False
            self._z = 0.0
            self._vx = self._vy = self._vz = 0.0
            self._rc = (0, 0, 0, 0)
            return None
        handler = self._HANDLERS.get(cmd)
        if handler is None:
            return self._read(cmd, args) if cmd.endswith("?") else f"unknown command: {cmd}"
        return handler(self, args, sender, now)

    def _on_rc(self, args: list[str]) -> None:
        try:
            values = [int(a) for a in args]
        except ValueError:
            return
        if len(values) != 4 or any(abs(v) > 100 for v in values):
            return  # a real Tello silently ignores malformed rc
        self._rc = (values[0], values[1], values[2], values[3])

    def _read(self, cmd: str, args: list[str]) -> str:
        if args:
            return "error"
        values: dict[str, Callable[[], str]] = {
            "speed?": lambda: str(self._speed_setting),
            "battery?": lambda: str(int(self._battery)),
            "height?": lambda: f"{round(self._z * 10)}dm",
            "time?": lambda: f"{int(self._motor_time)}s",
            "wifi?": lambda: str(self.wifi_snr),
            "sdk?": lambda: self.sdk_version,
            "sn?": lambda: self.serial,
            "tof?": lambda: f"{round(self._z * 1000) + 100}mm",
            "baro?": lambda: f"{100.0 + self._z:.2f}",
            "temp?": lambda: (
                f"{int(min(90.0, 60.0 + self._motor_time / 20.0))}~{int(min(90.0, 62.0 + self._motor_time / 20.0))}C"
            ),
            "attitude?": lambda: f"pitch:0;roll:0;yaw:{round(_wrap180(self._yaw))};",
        }
        getter = values.get(cmd)
        return getter() if getter else f"unknown command: {cmd}"

    def _cmd_takeoff(self, args: list[str], sender: Address, now: float) -> str | None:
        if self._flying or self.refuse_takeoff or self._battery < self.min_takeoff_battery:
            return "error"
        self._flying = True
        self._rc = (0, 0, 0, 0)
        self._maneuver = _Maneuver(
            "takeoff",
            (self._x, self._y, self.takeoff_height),
            speed=self.takeoff_height / max(self.takeoff_time, 1e-3),
            reply_to=sender,
            settle=self.takeoff_settle,
        )
        return None

    def _cmd_land(self, args: list[str], sender: Address, now: float) -> str | None:
        if not self._flying:
            return "error"
        self._start_landing(sender)
        return None

    def _start_landing(self, reply_to: Address | None) -> None:
        self._rc = (0, 0, 0, 0)
        self._maneuver = _Maneuver(
            "land", (self._x, self._y, 0.0), speed=self.land_speed, reply_to=reply_to, lands=True
        )

    def _cmd_ok(self, args: list[str], sender: Address, now: float) -> str | None:
        return "ok"

    def _cmd_streamon(self, args: list[str], sender: Address, now: float) -> str | None:
        self._stream_on = True
        return "ok"

    def _cmd_streamoff(self, args: list[str], sender: Address, now: float) -> str | None:
        self._stream_on = False
        return "ok"

    def _cmd_speed(self, args: list[str], sender: Address, now: float) -> str | None:
        value = _ints(args, 1)
        if value is None:
            return "error"
        if not 10 <= value[0] <= 100:
            return "out of range"
        self._speed_setting = value[0]
        return "ok"

    def _cmd_stop(self, args: list[str], sender: Address, now: float) -> str | None:
        if self._maneuver is not None and not self._maneuver.lands:
            self._maneuver = None
        self._rc = (0, 0, 0, 0)
        return "ok"

    def _motion_refusal(self) -> str | None:
        if not self._flying:
            return "error Motor stop"
        if self._maneuver is not None:
            return "error"
        return None

    def _cmd_move(self, cmd: str, args: list[str], sender: Address) -> str | None:
        value = _ints(args, 1)
        if value is None:
            return "error"
        if not 20 <= value[0] <= 500:
            return "out of range"
        refusal = self._motion_refusal()
        if refusal:
            return refusal
        d = value[0] / 100.0
        fwd, right, up = {
            "forward": (d, 0.0, 0.0),
            "back": (-d, 0.0, 0.0),
            "right": (0.0, d, 0.0),
            "left": (0.0, -d, 0.0),
            "up": (0.0, 0.0, d),
            "down": (0.0, 0.0, -d),
        }[cmd]
        self._start_relative(cmd, fwd, right, up, self._speed_setting / 100.0, sender)
        return None

    def _start_relative(
        self, name: str, fwd: float, right: float, up: float, speed: float, sender: Address
    ) -> None:
        yaw = math.radians(self._yaw)
        dx = fwd * math.cos(yaw) - right * math.sin(yaw)
        dy = fwd * math.sin(yaw) + right * math.cos(yaw)
        target = (self._x + dx, self._y + dy, max(0.1, self._z + up))
        self._rc = (0, 0, 0, 0)
        self._maneuver = _Maneuver(name, target, speed=speed, reply_to=sender)

    def _cmd_go(self, args: list[str], sender: Address, now: float) -> str | None:
        values = _ints(args, 4)
        if values is None:
            return "error"
        x, y, z, speed = values
        if not (all(-500 <= v <= 500 for v in (x, y, z)) and 10 <= speed <= 100):
            return "out of range"
        if all(-20 <= v <= 20 for v in (x, y, z)):
            return "out of range"
        refusal = self._motion_refusal()
        if refusal:
            return refusal
        self._start_relative("go", x / 100.0, -y / 100.0, z / 100.0, speed / 100.0, sender)
        return None

    def _cmd_rotate(self, cmd: str, args: list[str], sender: Address) -> str | None:
        value = _ints(args, 1)
        if value is None:
            return "error"
        if not 1 <= value[0] <= 3600:
            return "out of range"
        refusal = self._motion_refusal()
        if refusal:
            return refusal
        sign = 1.0 if cmd == "cw" else -1.0
        self._rc = (0, 0, 0, 0)
        self._maneuver = _Maneuver(
            cmd,
            (self._x, self._y, self._z),
            speed=0.0,
            yaw=self._yaw + sign * value[0],
            yaw_rate=self.rotate_rate,
            reply_to=sender,
        )
        return None

    def _cmd_flip(self, args: list[str], sender: Address, now: float) -> str | None:
        if len(args) != 1 or args[0] not in ("l", "r", "f", "b"):
            return "error"
        refusal = self._motion_refusal()
        if refusal:
            return refusal
        if self._battery < 50:
            return "error"
        self._maneuver = _Maneuver(
            "flip", (self._x, self._y, self._z), speed=0.0, reply_to=sender, hold_until=now + self.flip_time
        )
        return None

    _HANDLERS: dict[str, Callable[[TelloEmulator, list[str], Address, float], str | None]] = {
        "takeoff": _cmd_takeoff,
        "land": _cmd_land,
        "streamon": _cmd_streamon,
        "streamoff": _cmd_streamoff,
        "keepalive": _cmd_ok,
        "speed": _cmd_speed,
        "stop": _cmd_stop,
        "go": _cmd_go,
        "flip": _cmd_flip,
        **{name: _move_handler(name) for name in MOTION_COMMANDS},
        "cw": lambda self, args, sender, now: self._cmd_rotate("cw", args, sender),
        "ccw": lambda self, args, sender, now: self._cmd_rotate("ccw", args, sender),
    }

    # -- physics ---------------------------------------------------------------------------------

    def _step(self, dt: float, now: float) -> None:
        done: tuple[str, Address, str] | None = None
        with self._lock:
            if self._flying:
                self._motor_time += dt
                self._battery = max(0.0, self._battery - self.battery_drain * dt)
                if self._battery <= self.auto_land_battery and not (self._maneuver and self._maneuver.lands):
                    self._start_landing(None)
            if self._maneuver is not None:
                done = self._step_maneuver(dt, now)
            elif self._flying:
                self._step_rc(dt)
                if now - self._last_command > self.auto_land_timeout:
                    LOG.info("no command for %.1f s: auto-landing", self.auto_land_timeout)
                    self._start_landing(None)
            else:
                self._vx = self._vy = self._vz = 0.0
        if done is not None:
            self._reply(*done)

    def _step_maneuver(self, dt: float, now: float) -> tuple[str, Address, str] | None:
        m = self._maneuver
        assert m is not None
        dx, dy, dz = m.target[0] - self._x, m.target[1] - self._y, m.target[2] - self._z
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        step = m.speed * dt
        if dist <= step or dist < 1e-6:
            self._vx = self._vy = self._vz = 0.0
            self._x, self._y, self._z = m.target
            at_target = True
        else:
            k = step / dist
            self._vx, self._vy, self._vz = dx * k / dt, dy * k / dt, dz * k / dt
            self._x += dx * k
            self._y += dy * k
            self._z += dz * k
            at_target = False
        if m.yaw is not None:
            dyaw = m.yaw - self._yaw
            turn = m.yaw_rate * dt
            if abs(dyaw) <= turn:
                self._yaw = m.yaw
            else:
                self._yaw += math.copysign(turn, dyaw)
                at_target = False
        if at_target and m.reached_at is None:
            m.reached_at = now
        if not at_target or now < m.hold_until or now < (m.reached_at or now) + m.settle:
            return None
        self._maneuver = None
        self._last_command = now  # the 15 s auto-land count starts when a command has been executed
        if m.lands:
            self._flying = False
            self._z = 0.0
        return ("ok", m.reply_to, m.name) if m.reply_to is not None else None

    def _step_rc(self, dt: float) -> None:
        lr, fb, ud, yw = self._rc
        fwd = fb / 100.0 * self.max_speed
        right = lr / 100.0 * self.max_speed
        up = ud / 100.0 * self.max_vertical_speed
        yaw = math.radians(self._yaw)
        cmd_vx = fwd * math.cos(yaw) - right * math.sin(yaw)
        cmd_vy = fwd * math.sin(yaw) + right * math.cos(yaw)
        alpha = 1.0 - math.exp(-dt / self.response_tau) if self.response_tau > 0 else 1.0
        tau_z = self.response_tau if self.vertical_tau is None else self.vertical_tau
        alpha_z = 1.0 - math.exp(-dt / tau_z) if tau_z > 0 else 1.0
        self._vx += (cmd_vx - self._vx) * alpha
        self._vy += (cmd_vy - self._vy) * alpha
        self._vz += (up - self._vz) * alpha_z
        self._x += self._vx * dt
        self._y += self._vy * dt
        self._z += self._vz * dt
        if self._z < 0.1:  # the Tello will not descend onto the ground under rc; it hovers low
            self._z = 0.1
            self._vz = max(self._vz, 0.0)
        self._yaw += yw / 100.0 * self.max_yaw_rate * dt


def _ints(args: list[str], n: int) -> list[int] | None:
    if len(args) != n:
        return None
    try:
        return [int(a) for a in args]
    except ValueError:
        return None


def _address(text: str) -> Address:
    host, _, port = text.rpartition(":")
    return (host, int(port))


def main(argv: list[str] | None = None) -> int:
    """Run an emulator until SIGTERM/SIGINT (for tests that need it in another process or namespace)."""
    parser = argparse.ArgumentParser(
        prog="python -m tests.emulators.tello_emulator", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8889)
    parser.add_argument("--state-port", type=int, default=8890)
    parser.add_argument("--state-target", type=_address, default=None, help="HOST:PORT for state packets")
    parser.add_argument("--takeoff-time", type=float, default=2.5)
    parser.add_argument("--takeoff-height", type=float, default=0.8)
    parser.add_argument("--takeoff-settle", type=float, default=0.0, help="s hovering before takeoff's ok")
    parser.add_argument("--land-speed", type=float, default=0.6)
    parser.add_argument("--max-speed", type=float, default=1.0, help="m/s at rc 100")
    parser.add_argument("--auto-land-timeout", type=float, default=15.0)
    parser.add_argument("--battery", type=float, default=100.0)
    parser.add_argument("--battery-drain", type=float, default=0.1, help="%%/s in flight")
    parser.add_argument("--refuse-takeoff", action="store_true")
    parser.add_argument("--vertical-tau", type=float, default=None, help="s: vertical response to rc")
    parser.add_argument("--height-resolution-cm", type=int, default=10)
    parser.add_argument("--height-rounding", choices=("round", "floor"), default="round")
    parser.add_argument(
        "--lose-reply",
        action="append",
        default=[],
        metavar="COMMAND",
        help="lose the first answer to COMMAND (repeatable)",
    )
    parser.add_argument("--log-level", default="WARNING")
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(name)s %(message)s")

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    emu = TelloEmulator(
        args.host,
        args.port,
        state_port=args.state_port,
        state_target=args.state_target,
        takeoff_time=args.takeoff_time,
        takeoff_settle=args.takeoff_settle,
        takeoff_height=args.takeoff_height,
        land_speed=args.land_speed,
        max_speed=args.max_speed,
        auto_land_timeout=args.auto_land_timeout,
        battery=args.battery,
        battery_drain=args.battery_drain,
        vertical_tau=args.vertical_tau,
        height_resolution_cm=args.height_resolution_cm,
        height_rounding=args.height_rounding,
    )
    emu.refuse_takeoff = args.refuse_takeoff
    for command in args.lose_reply:
        emu.lose_reply(command)
    with emu:
        print(f"READY {emu.address[0]} {emu.address[1]}", flush=True)
        while not stop.wait(0.2):
            pass
        snap = asdict(emu.snapshot())
        snap["commands"] = emu.command_texts()
    print(json.dumps(snap), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
