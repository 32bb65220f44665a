"""`TelloAutopilot`: a DJI/Ryze Tello over Wi-Fi through djitellopy (docs/design.md §7, ``tello``).

The Tello speaks the SDK text protocol: commands to UDP 8889 (most answered ``ok``/``error`` once
*done*, ``rc`` never answered), and a state line pushed to UDP 8890 about ten times a second. It
has no GPS, no arming step and no return-to-home, so this adapter supplies what the HLC expects on
top of it. The user-facing description (set-up, several Tellos, limits) is ``docs/tello.md``.

What the adapter adds, and why
------------------------------
* **Position by dead reckoning.** The state line carries ground velocities ``vgx/vgy`` (dm/s) and
  ``yaw`` (deg, 0 at power-on). They are rotated into north/east by ``home_heading`` (the compass
  heading the Tello faced at power-on) and integrated (trapezoid rule, only while flying) from the
  configured ``home_lat``/``home_lon``. Heading = ``home_heading + yaw``. Altitude is the state's
  ``h`` (cm above the take-off point, decimetre resolution) or, with ``altitude_source = "tof"``, the
  downward range finder. The frame of ``vgx/vgy`` follows the test emulator's reading of the SDK
  (``tests/emulators/tello_emulator.py``: a ground frame fixed at power-on, x along yaw 0, y to the
  right); real units have been reported with other signs and frames, hence ``vgx_sign``,
  ``vgy_sign`` and ``velocity_frame``. Dead reckoning drifts: it is for a flying field, not a route.
* **Link age.** djitellopy's receiver thread replaces the per-drone state dict on every packet, so a
  new dict object means a new packet. Both `state()` and the control thread poll for that and
  stamp it with the adapter's clock; ``link_age`` is the age of the newest stamp. Polling from both
  keeps the stamps fresh while the control thread is blocked in a ``land`` (which only answers
  once the Tello is down).
* **A control thread** (``control_hz``) that streams ``rc`` while a velocity set-point, the take-off
  climb or the RTL leg is active, and sends ``rc 0 0 0 0`` every ``keepalive_s`` while the Tello
  hovers idle: a Tello lands itself 15 s after the last command. ``rc`` is used as the keepalive,
  not the ``keepalive`` command, because ``rc`` is never answered: an answered command would share
  djitellopy's single reply queue with the HLC's blocking commands, where a late reply is taken as
  the answer to the next command. When no state has arrived for ``link_loss_timeout`` s the thread
  sends one ``rc 0 0 0 0`` (hover) and then stays silent, so that the Tello's own 15 s failsafe
  lands it instead of it hovering on our keepalives while nobody can see it; if the state comes
  back first, the adapter lands it (a link loss in flight ends the flight: the HLC's LLC_DOWN is
  final, and nobody would command the Tello again).
* **RTL** = fly back to the take-off point (the dead-reckoned position where the last take-off
  began) at ``rtl_speed`` with ``rc``, slowing down over the last metre, then ``land`` within
  ``rtl_tolerance``. It is asynchronous: `rtl` returns at once, the mode is ``RTL`` on the way and
  ``LAND`` for the final descent. If the distance grows instead of shrinking (a wrong sign
  convention) or the leg takes far longer than it should, the Tello lands where it is.
* **Take-off to an altitude.** The Tello's own ``takeoff`` stops at about 0.8 m. With
  ``takeoff_altitude_mode = "rc"`` (default) `takeoff` returns once that is done and the control
  thread climbs (or descends) to the target with ``rc`` (mode ``TAKEOFF`` until within 0.1 m, then
  ``GUIDED``); the HLC watches the altitude as for any vehicle, and a velocity set-point ends the
  climb. With ``"up"`` `takeoff` also sends ``up``/``down`` (20..500 cm each, answered once done)
  and returns only at the altitude; a remainder under 20 cm is trimmed with ``rc``.
* **No arming.** The motors start with ``takeoff``. `arm` checks that the link is alive, that a
  command is answered (``battery?``) and that the battery is above ``min_battery``; `disarm` is a
  no-op on the ground (it never sends ``emergency``, which cuts the motors in flight).

The ``rc`` scale: an ``rc`` value of 100 is taken to mean ``max_speed`` m/s horizontally,
``max_vertical_speed`` m/s vertically and ``max_yaw_rate`` deg/s, linearly; set-points are scaled by
these and clamped to ±100 (horizontal components together, so the direction is kept). The defaults
match the test emulator; measure your Tello's and set them (see ``docs/tello.md``).

One process, several Tellos: djitellopy binds UDP 8889 and 8890 on all addresses once per process
and files replies and state packets by the sender's IP. Several Tellos are therefore several agents
of one ``antalate agent`` process, each with its own ``host``; a second process on the same machine
cannot bind the ports, and two adapters in one process cannot share a host.
"""

from __future__ import annotations

import contextlib
import enum
import ipaddress
import logging
import math
import threading
import time
from collections.abc import Mapping
from typing import Any

from antalate_lcm._ratelimit import RateLimitedLog
from antalate_lcm.autopilot.base import Autopilot, AutopilotError, AutopilotState, Clock, FlightMode, Frame
from antalate_lcm.geo import FlatFrame, wrap_360

log = logging.getLogger("antalate.autopilot.tello")

#: Parameters and their defaults (``[hlc.autopilot_params]`` with ``autopilot = "tello"``).
DEFAULTS: dict[str, Any] = {
    "host": "192.168.10.1",  # the Tello's IP (192.168.10.1 in its own access-point mode)
    "home_lat": 32.7767,  # deg: where the Tello was powered on (dead-reckoning origin)
    "home_lon": 35.0231,  # deg
    "home_heading": 0.0,  # deg from north: where the Tello faced at power-on (its yaw 0)
    "max_speed": 1.0,  # m/s horizontally at rc 100
    "max_vertical_speed": 1.0,  # m/s at rc 100
    "max_yaw_rate": 100.0,  # deg/s at rc 100
    "control_hz": 20.0,  # rate of the control thread (rc streaming, RTL, climb)
    "keepalive_s": 5.0,  # s between keepalive rc while hovering idle (the Tello lands after 15 s)
    "velocity_hold": 1.0,  # s a velocity set-point is streamed without being renewed
    "rtl_speed": 0.5,  # m/s on the way back to the take-off point
    "rtl_tolerance": 0.3,  # m from the take-off point at which the RTL lands
    "vgx_sign": 1,  # +1 or -1: sign of the state's vgx (forward along yaw 0 is positive)
    "vgy_sign": 1,  # +1 or -1: sign of the state's vgy (right of yaw 0 is positive)
    "velocity_frame": "ground",  # "ground": vgx/vgy in the power-on frame; "body": along the current yaw
    "altitude_source": "h",  # "h": the state's height; "tof": the downward range finder
    "takeoff_altitude_mode": "rc",  # "rc": climb with rc in the background; "up": blocking up/down
    "min_battery": 10.0,  # percent: arm() refuses at or below (the Tello refuses takeoff near 10%)
    "command_timeout": 7,  # s (integer, djitellopy's unit) to wait for a command's answer
    "takeoff_timeout": 20,  # s (integer) for takeoff, land and up/down, answered only when done
    "retry_count": 3,  # attempts per answered command (djitellopy resends on error or timeout)
    "state_timeout": 2.0,  # s connect() waits for the first state packet
    "link_loss_timeout": 2.0,  # s without state before the adapter stops commanding the Tello
    "djitellopy_log_level": "WARNING",  # djitellopy logs every command at INFO (rc at 20 Hz...)
}

_CLIMB_TOLERANCE = 0.1  # m: the climb to the take-off altitude is done within this
_CLIMB_GAIN = 1.5  # 1/s: vertical speed per metre of remaining climb
_MIN_CLIMB_SPEED = 0.2  # m/s: so the last centimetres do not take forever
_APPROACH_GAIN = 1.0  # 1/s: RTL speed per metre of remaining distance (below rtl_speed)
_MIN_APPROACH_SPEED = 0.2  # m/s
_RTL_DIVERGENCE = 2.0  # m: farther than the start distance by this much -> give up and land here
_GROUND_CONFIRM = 0.5  # s of zero height before a flying Tello counts as landed on its own
_LAND_RETRY = 2.0  # s between attempts when a land command failed in the air
_STOP_REPEAT = 3  # zero rc sent this many ticks in a row when motion stops (UDP may drop one)
_UP_MIN_CM, _UP_MAX_CM = 20, 500  # the SDK's range for up/down
_TOF_GROUND_CM = 10  # the range finder reads this on the ground
_TOF_INVALID_CM = 6000  # and implausibly large values out of range

#: Hosts with a live adapter in this process: djitellopy keeps one reply queue per IP.
_HOSTS_IN_USE: set[str] = set()
_HOSTS_LOCK = threading.Lock()


class _Phase(enum.Enum):
    """What the adapter is doing; the value is the mode name shown in telemetry."""

    GROUND = "GROUND"
    TAKEOFF = "TAKEOFF"  # the Tello's takeoff, then the climb to the target altitude
    GUIDED = "GUIDED"  # hovering or following velocity set-points
    RTL = "RTL"  # flying back to the take-off point
    LAND = "LAND"  # landing (a land command, or the end of an RTL)


_FLIGHT_MODES = {_Phase.RTL: FlightMode.RTL, _Phase.LAND: FlightMode.LANDING}


def _validated(params: Mapping[str, Any]) -> dict[str, Any]:
    """Defaults merged with `params`, every value checked; `ValueError` names the offending key."""
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown tello autopilot parameter(s) {unknown}; known: {sorted(DEFAULTS)}")
    p = {**DEFAULTS, **params}

    def number(key: str, *, positive: bool = True) -> float:
        value = p[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"tello autopilot parameter {key!r} must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise ValueError(f"tello autopilot parameter {key!r} must be > 0, got {value!r}")
        return float(value)

    try:
        ipaddress.IPv4Address(str(p["host"]))
    except ValueError:
        raise ValueError(
            f"tello autopilot parameter 'host' must be an IPv4 address, got {p['host']!r} "
            "(djitellopy matches replies to drones by the sender's IP)"
        ) from None
    p["host"] = str(p["host"])
    for key in ("home_lat", "home_lon", "home_heading", "min_battery"):
        p[key] = number(key, positive=False)
    if not -90.0 <= p["home_lat"] <= 90.0:
        raise ValueError(f"tello autopilot parameter 'home_lat' must be in [-90, 90], got {p['home_lat']!r}")
    for key in ("max_speed", "max_vertical_speed", "max_yaw_rate", "control_hz", "keepalive_s", "velocity_hold",
                "rtl_speed", "rtl_tolerance", "state_timeout", "link_loss_timeout"):
        p[key] = number(key)
    if p["keepalive_s"] >= 15.0:
        raise ValueError(f"tello autopilot parameter 'keepalive_s' must be < 15 (the Tello lands after 15 s "
                         f"without a command), got {p['keepalive_s']!r}")
    for key in ("command_timeout", "takeoff_timeout", "retry_count"):
        value = p[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"tello autopilot parameter {key!r} must be an integer >= 1 "
                             f"(djitellopy takes whole seconds), got {value!r}")
    for key in ("vgx_sign", "vgy_sign"):
        if p[key] not in (1, -1) or isinstance(p[key], bool):
            raise ValueError(f"tello autopilot parameter {key!r} must be 1 or -1, got {p[key]!r}")
    choices = {
        "velocity_frame": ("ground", "body"),
        "altitude_source": ("h", "tof"),
        "takeoff_altitude_mode": ("rc", "up"),
    }
    for key, allowed in choices.items():
        if p[key] not in allowed:
            raise ValueError(f"tello autopilot parameter {key!r} must be one of {list(allowed)}, got {p[key]!r}")
    level = p["djitellopy_log_level"]
    if not isinstance(level, str) or not isinstance(logging.getLevelName(level.upper()), int):
        raise ValueError(f"tello autopilot parameter 'djitellopy_log_level' must be a logging level name, "
                         f"got {level!r}")
    return p


class TelloAutopilot(Autopilot):
    """A Tello through djitellopy; see the module docstring for what is emulated on top of the SDK."""

    name = "tello"
    blocking = True  # takeoff/land/up wait for the Tello's answer, which comes when the move is done

    def __init__(self, params: Mapping[str, Any] | None = None, *, clock: Clock = time.monotonic) -> None:
        super().__init__(params, clock=clock)
        p = _validated(self.params)
        self._p = p
        self.host: str = p["host"]
        self.home = FlatFrame(p["home_lat"], p["home_lon"])
        self._home_heading = wrap_360(p["home_heading"])
        self._tello: Any = None  # djitellopy.Tello once connected
        self._tello_error: type[Exception] = Exception  # djitellopy.TelloException once imported
        self._lock = threading.RLock()  # adapter state, shared by the HLC, control and caller threads
        self._cmd_lock = threading.Lock()  # one answered command at a time (one reply queue per host)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected = False
        self._owns_host = False
        self._ratelog = RateLimitedLog(log, period=10.0)
        # Telemetry from the newest state packet.
        self._raw: dict[str, Any] | None = None  # the dict object of the last packet (identity = packet)
        self._state_time: float | None = None  # clock() when it was first seen
        self._yaw = 0.0  # deg, the Tello's own (0 at power-on)
        self._vn = self._ve = self._vd = 0.0  # m/s
        self._height = 0.0  # m above the take-off point
        self._h_cm = 0  # the raw height, the in-air test
        self._battery = -1.0
        # Dead reckoning (metres north/east of home).
        self._north = self._east = 0.0
        self._takeoff_point = (0.0, 0.0)
        # What the adapter is doing.
        self._phase = _Phase.GROUND
        self._climb_target: float | None = None  # m; set while the rc climb is active
        self._setpoint: tuple[float, float, float, float, Frame] | None = None  # vx, vy, vz, yaw_rate, frame
        self._setpoint_time = 0.0
        self._rtl_start = 0.0
        self._rtl_dist0 = 0.0
        self._land_due: float | None = None  # clock() at which the control thread (re)tries land
        self._ground_since: float | None = None  # first zero-height packet while flying
        self._last_sent = -math.inf  # clock() of the last datagram sent to the Tello
        self._stop_ticks = 0  # zero rc still to send after motion stopped
        self._silenced = False  # link lost: no more commands until state comes back

    # ================================================================= the Autopilot contract

    def connect(self) -> None:
        if self._connected:
            return
        try:
            from djitellopy import Tello, TelloException
        except ImportError as exc:  # pragma: no cover - djitellopy is a dependency of antalate
            raise AutopilotError(f"djitellopy is not installed ({exc}): pip install djitellopy") from exc
        Tello.LOGGER.setLevel(self._p["djitellopy_log_level"].upper())
        # djitellopy prints through a handler of its own *and* propagates to the root logger, so
        # every line appeared twice; the application's logging configuration is the one to keep.
        Tello.LOGGER.removeHandler(Tello.HANDLER)
        self._tello_error = TelloException
        with _HOSTS_LOCK:
            if not self._owns_host and self.host in _HOSTS_IN_USE:
                raise AutopilotError(
                    f"another tello autopilot in this process already flies {self.host}: "
                    "djitellopy keeps one reply queue per IP, so each agent needs its own Tello")
            _HOSTS_IN_USE.add(self.host)
            self._owns_host = True
        try:
            self._open(Tello)
        except BaseException:
            self._release()
            raise
        self._stop.clear()
        self._thread = threading.Thread(target=self._control_loop, name=f"tello-{self.host}", daemon=True)
        self._connected = True
        self._thread.start()
        log.info("Tello %s connected: battery %s%%, %s", self.host, self._battery,
                 "flying" if self._phase is not _Phase.GROUND else "on the ground")

    def close(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        tello = self._tello
        if tello is not None and self._connected:
            with self._lock:
                flying = self._phase is not _Phase.GROUND
            if flying:
                # Hover and let go: the Tello's own 15 s failsafe lands it unless a restarted HLC
                # takes over first (a vehicle outlives the software flying it).
                self._send_rc((0, 0, 0, 0))
                log.warning("Tello %s left hovering; it lands itself 15 s after the last command", self.host)
        self._connected = False
        self._release()

    def arm(self) -> bool:
        self._require_link("arm")
        answer = self._ask("battery?")
        try:
            battery = float(answer)
        except ValueError:
            raise AutopilotError(f"arm: the Tello at {self.host} did not answer 'battery?' ({answer!r})") from None
        if battery <= self._p["min_battery"]:
            log.warning("arm refused: battery %.0f%% <= min_battery %g%%", battery, self._p["min_battery"])
            return False
        return True

    def disarm(self) -> None:
        self._require_connected("disarm")
        with self._lock:
            if self._in_air():
                raise AutopilotError("disarm refused: the Tello is flying (its only disarm, 'emergency', "
                                     "cuts the motors in the air)")

    def takeoff(self, alt: float) -> None:
        self._require_link("takeoff")
        if not (math.isfinite(alt) and alt > 0.0):
            raise AutopilotError(f"takeoff refused: altitude {alt!r} must be > 0")
        with self._lock:
            if self._phase is not _Phase.GROUND or self._in_air():
                raise AutopilotError(f"takeoff refused: already {self._phase.value.lower()} "
                                     f"at {self._height:.1f} m")
            self._phase = _Phase.TAKEOFF
            self._takeoff_point = (self._north, self._east)
            self._setpoint = None
            self._climb_target = None
        try:
            self._command("takeoff", self._p["takeoff_timeout"])
        except AutopilotError:
            with self._lock:
                self._phase = _Phase.GUIDED if self._in_air() else _Phase.GROUND
            raise
        if self._p["takeoff_altitude_mode"] == "up":
            self._climb_with_up(alt)
        else:
            self._wait_fresh_state()  # the height when "ok" came, not from a packet sent mid-climb
        with self._lock:
            if self._phase is _Phase.TAKEOFF:
                if abs(alt - self._height) <= _CLIMB_TOLERANCE:
                    self._phase = _Phase.GUIDED
                else:
                    self._climb_target = alt  # the control thread takes it from here

    def land(self) -> None:
        self._require_connected("land")
        with self._lock:
            self._setpoint = None
            self._climb_target = None
            if self._phase is _Phase.GROUND and not self._in_air():
                return  # nothing to land
            self._phase = _Phase.LAND
            self._land_due = None
        self._send_rc((0, 0, 0, 0))
        self._land_now()

    def rtl(self) -> None:
        self._require_link("rtl")
        with self._lock:
            if not self._in_air() and self._phase in (_Phase.GROUND, _Phase.TAKEOFF):
                return  # on the ground there is nowhere to return from
            if self._phase in (_Phase.RTL, _Phase.LAND):
                return  # already on the way (or down)
            self._setpoint = None
            self._climb_target = None
            self._phase = _Phase.RTL
            self._rtl_start = self.clock()
            tn, te = self._takeoff_point
            self._rtl_dist0 = math.hypot(tn - self._north, te - self._east)
            log.info("Tello %s RTL: %.1f m to the take-off point", self.host, self._rtl_dist0)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        values = (vx, vy, vz, yaw_rate)
        if not all(math.isfinite(v) for v in values):
            raise AutopilotError(f"velocity refused: non-finite value in {values}")
        self._require_link("set_velocity")
        with self._lock:
            self._ingest()
            if self._phase is _Phase.TAKEOFF and self._climb_target is not None:
                self._climb_target = None  # the caller takes over from the climb
                self._phase = _Phase.GUIDED
            if self._phase is not _Phase.GUIDED:
                return  # like ArduCopter: velocity targets are ignored outside guided flight
            self._setpoint = (vx, vy, vz, yaw_rate, Frame(frame))
            self._setpoint_time = self.clock()
            rc = self._setpoint_rc()
        self._send_rc(rc)

    def state(self) -> AutopilotState:
        with self._lock:
            if not self._connected:
                return AutopilotState(connected=False, link_age=math.inf)
            self._ingest()
            lat, lon = self.home.to_latlon(self._north, self._east)
            # Until the Tello confirms a landing the motors may still turn: the HLC must not see
            # "landed" (and command the next take-off) while the final centimetres, which the state's
            # decimetre height already rounds to zero, are being flown.
            in_air = self._in_air() or self._phase is _Phase.LAND
            return AutopilotState(
                connected=True,
                link_age=self._link_age(),
                lat=lat,
                lon=lon,
                alt=self._height,
                heading=self._heading(),
                vn=self._vn,
                ve=self._ve,
                vd=self._vd,
                battery=self._battery,
                armed=in_air,  # a Tello's motors run exactly while it flies
                in_air=in_air,
                autonomous=True,  # no pilot radio: always under computer control
                mode=self._phase.value,
                flight_mode=_FLIGHT_MODES.get(self._phase, FlightMode.GUIDED),
            )

    # ================================================================= extras (tests, tools)

    @property
    def position_ne(self) -> tuple[float, float]:
        """Dead-reckoned metres north/east of home (for tests and tools)."""
        with self._lock:
            return self._north, self._east

    @property
    def takeoff_point(self) -> tuple[float, float]:
        """Where the last take-off began, metres north/east of home: the RTL's destination."""
        with self._lock:
            return self._takeoff_point

    # ================================================================= link and commands

    def _open(self, tello_cls: Any) -> None:
        """Make the djitellopy client, enter SDK mode, wait for state (connect's I/O).

        This is ``Tello.connect()`` done by hand: djitellopy's own waits 3 x 7 s for an answer and
        1 s for state, fixed; a dead host must fail in ``command_timeout`` x ``retry_count`` s, and
        each failure must say what to check.
        """
        p = self._p
        try:
            tello = tello_cls(self.host, retry_count=p["retry_count"])
        except OSError as exc:
            raise AutopilotError(
                f"cannot bind UDP {tello_cls.CONTROL_UDP_PORT} for djitellopy ({exc}): another process on "
                "this machine talks to a Tello; run every Tello agent in one process "
                "(antalate agent tello-a.toml tello-b.toml)") from exc
        self._tello = tello
        try:
            self._command("command", p["command_timeout"])
        except AutopilotError as exc:
            raise AutopilotError(
                f"no answer from the Tello at {self.host}:{tello_cls.CONTROL_UDP_PORT} to 'command' "
                f"({p['retry_count']} x {p['command_timeout']} s): is it on, and is this machine on its "
                f"Wi-Fi (or it on yours, in station mode)? ({exc})") from exc
        deadline = time.monotonic() + p["state_timeout"]
        while True:
            with self._lock:
                self._ingest()
                if self._state_time is not None:
                    self._phase = _Phase.GUIDED if self._in_air() else _Phase.GROUND
                    self._takeoff_point = (self._north, self._east)
                    return
            if time.monotonic() >= deadline:
                raise AutopilotError(
                    f"the Tello at {self.host} entered SDK mode but sent no state packet to UDP "
                    f"{tello_cls.STATE_UDP_PORT} within {p['state_timeout']:g} s (a firewall, or another "
                    "program bound to that port?)")
            time.sleep(0.02)

    def _release(self) -> None:
        tello, self._tello = self._tello, None
        if tello is not None:
            tello.is_flying = False  # djitellopy's end()/__del__ would otherwise block on a land
            try:
                tello.end()  # drops this host from djitellopy's tables
            except Exception:  # noqa: BLE001 - closing must not fail
                log.debug("djitellopy end() failed", exc_info=True)
            # end() runs again from Tello.__del__, whenever the object is collected; by then a new
            # adapter may have registered the same host, whose entry it would delete. Point this
            # object at no host so that second end() finds nothing to remove.
            tello.address = ("closed", tello.address[1])
        with _HOSTS_LOCK:
            if self._owns_host:
                _HOSTS_IN_USE.discard(self.host)
                self._owns_host = False

    def _require_connected(self, what: str) -> None:
        if not self._connected or self._tello is None:
            raise AutopilotError(f"{what}: not connected to the Tello at {self.host}")

    def _require_link(self, what: str) -> None:
        self._require_connected(what)
        with self._lock:
            self._ingest()
            age = self._link_age()
        if age > self._p["link_loss_timeout"]:
            raise AutopilotError(f"{what}: no state from the Tello at {self.host} for {age:.1f} s (link lost)")

    def _clear_replies(self) -> None:
        """Drop late replies to earlier commands, which djitellopy would take as this command's answer."""
        with contextlib.suppress(KeyError, AttributeError, TypeError):
            self._tello.get_own_udp_object()["responses"].clear()

    def _command(self, text: str, timeout: int) -> None:
        """Send an answered control command; `AutopilotError` unless the Tello says ``ok``."""
        with self._cmd_lock:
            self._command_locked(text, timeout)

    def _command_locked(self, text: str, timeout: int) -> None:
        tello = self._tello
        if tello is None:
            raise AutopilotError(f"{text}: not connected")
        self._clear_replies()
        self._last_sent = self.clock()
        try:
            tello.send_control_command(text, timeout=int(timeout))
        except self._tello_error as exc:
            raise AutopilotError(f"the Tello at {self.host} refused or did not answer {text!r}: {exc}") from exc
        except (KeyError, OSError) as exc:  # closed under us (djitellopy forgot the host), or no route
            raise AutopilotError(f"{text!r} to the Tello at {self.host} failed: {exc!r}") from exc
        finally:
            self._last_sent = self.clock()

    def _ask(self, text: str) -> str:
        """Send a read command (``battery?``) and return the answer."""
        tello = self._tello
        if tello is None:
            raise AutopilotError(f"{text}: not connected")
        with self._cmd_lock:
            self._clear_replies()
            try:
                answer = str(tello.send_command_with_return(text, timeout=int(self._p["command_timeout"])))
            except (KeyError, OSError) as exc:
                raise AutopilotError(f"{text!r} to the Tello at {self.host} failed: {exc!r}") from exc
            finally:
                self._last_sent = self.clock()
        return answer.strip()

    def _send_rc(self, rc: tuple[int, int, int, int]) -> None:
        """Send ``rc`` (never answered, so no lock: it cannot confuse the reply queue)."""
        tello = self._tello
        if tello is None:
            return
        try:
            tello.send_rc_control(*rc)
        except Exception as exc:  # noqa: BLE001 - a failed send is a lost datagram, not a crash
            self._ratelog.log(("rc",), logging.WARNING, "Tello %s: rc not sent: %s", self.host, exc)
            return
        self._last_sent = self.clock()

    def _land_now(self) -> None:
        """Send ``land`` unless the Tello is already down; on failure the control thread retries.

        The check is made holding the command lock, so when the HLC's `land` and the end of an RTL
        meet, the second finds the Tello on the ground instead of sending a second ``land``.
        """
        with self._cmd_lock:
            with self._lock:
                self._ingest()
                if self._phase is not _Phase.LAND:
                    return
                if not self._in_air():
                    self._phase = _Phase.GROUND
                    return
            try:
                self._command_locked("land", self._p["takeoff_timeout"])
            except AutopilotError:
                with self._lock:
                    self._ingest()
                    if not self._in_air():
                        self._phase = _Phase.GROUND  # came down anyway
                        return
                    self._land_due = self.clock() + _LAND_RETRY
                raise
            with self._lock:
                self._phase = _Phase.GROUND
                self._land_due = None

    def _climb_with_up(self, alt: float) -> None:
        """``takeoff_altitude_mode = "up"``: blocking up/down to within 20 cm; rc trims the rest."""
        for _ in range(4):
            self._wait_fresh_state()
            with self._lock:
                delta = alt - self._height
            cm = round(abs(delta) * 100)
            if cm < _UP_MIN_CM:
                return
            self._command(f"{'up' if delta > 0 else 'down'} {min(cm, _UP_MAX_CM)}", self._p["takeoff_timeout"])

    def _wait_fresh_state(self, timeout: float = 0.5) -> None:
        start = self.clock()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                self._ingest()
                if self._state_time is not None and self._state_time > start:
                    return
            time.sleep(0.02)

    # ================================================================= state packets, dead reckoning

    def _ingest(self) -> None:
        """Take in the newest state packet, if djitellopy received one since the last call (lock held)."""
        tello = self._tello
        if tello is None:
            return
        try:
            raw = tello.get_current_state()
        except (KeyError, AttributeError):
            return  # closed under us
        if not raw or raw is self._raw:
            return
        now = self.clock()
        self._raw = raw
        previous = self._state_time
        self._state_time = now
        vn0, ve0 = self._vn, self._ve
        p = self._p
        self._yaw = float(raw.get("yaw", self._yaw))
        gx = p["vgx_sign"] * float(raw.get("vgx", 0)) / 10.0
        gy = p["vgy_sign"] * float(raw.get("vgy", 0)) / 10.0
        if p["velocity_frame"] == "body":
            yaw = math.radians(self._yaw)
            gx, gy = gx * math.cos(yaw) - gy * math.sin(yaw), gx * math.sin(yaw) + gy * math.cos(yaw)
        psi0 = math.radians(self._home_heading)
        self._vn = gx * math.cos(psi0) - gy * math.sin(psi0)
        self._ve = gx * math.sin(psi0) + gy * math.cos(psi0)
        self._vd = float(raw.get("vgz", 0)) / 10.0
        self._h_cm = int(raw.get("h", self._h_cm))
        height = self._h_cm / 100.0
        if p["altitude_source"] == "tof":
            tof = int(raw.get("tof", 0))
            if 0 < tof < _TOF_INVALID_CM:
                height = max(0.0, (tof - _TOF_GROUND_CM) / 100.0)
        self._height = max(0.0, height)
        if "bat" in raw:
            self._battery = float(raw["bat"])
        if previous is not None and self._in_air():
            dt = now - previous
            self._north += 0.5 * (vn0 + self._vn) * dt
            self._east += 0.5 * (ve0 + self._ve) * dt
        self._track_ground(now)

    def _track_ground(self, now: float) -> None:
        """Notice a Tello that landed (or took off) without us: its own failsafes, another client."""
        flying_phase = self._phase in (_Phase.GUIDED, _Phase.RTL, _Phase.LAND)
        if flying_phase and not self._in_air() and not self._cmd_lock.locked():
            if self._ground_since is None:
                self._ground_since = now
            elif now - self._ground_since >= _GROUND_CONFIRM:
                if self._phase is not _Phase.LAND:
                    log.warning("Tello %s is on the ground (landed by itself: battery, or 15 s without a "
                                "command?)", self.host)
                self._phase = _Phase.GROUND
                self._setpoint = None
                self._land_due = None
        elif self._phase is _Phase.GROUND and self._in_air() and not self._cmd_lock.locked():
            if self._ground_since is None:
                self._ground_since = now
            elif now - self._ground_since >= _GROUND_CONFIRM:
                log.warning("Tello %s is flying though we did not take off: hovering under our control", self.host)
                self._phase = _Phase.GUIDED
        else:
            self._ground_since = None

    def _in_air(self) -> bool:
        """What the state packets say (height above zero); `state` adds the landing in progress."""
        return self._h_cm > 0

    def _link_age(self) -> float:
        return math.inf if self._state_time is None else max(0.0, self.clock() - self._state_time)

    def _heading(self) -> float:
        return wrap_360(self._home_heading + self._yaw)

    # ================================================================= rc

    def _rc(self, fwd: float, right: float, up: float, yaw_rate: float) -> tuple[int, int, int, int]:
        """Body-frame m/s (and deg/s) to rc sticks; horizontal scaled together so the direction holds."""
        p = self._p
        lr = right / p["max_speed"] * 100.0
        fb = fwd / p["max_speed"] * 100.0
        biggest = max(abs(lr), abs(fb))
        if biggest > 100.0:
            lr, fb = lr * 100.0 / biggest, fb * 100.0 / biggest

        def stick(value: float) -> int:
            return int(round(max(-100.0, min(100.0, value))))

        return (stick(lr), stick(fb), stick(up / p["max_vertical_speed"] * 100.0),
                stick(yaw_rate / p["max_yaw_rate"] * 100.0))

    def _ned_rc(self, vn: float, ve: float, up: float, yaw_rate: float) -> tuple[int, int, int, int]:
        psi = math.radians(self._heading())
        fwd = vn * math.cos(psi) + ve * math.sin(psi)
        right = -vn * math.sin(psi) + ve * math.cos(psi)
        return self._rc(fwd, right, up, yaw_rate)

    def _setpoint_rc(self) -> tuple[int, int, int, int]:
        """The set-point as rc, recomputed each tick so a NED set-point stays NED while yawing."""
        assert self._setpoint is not None
        vx, vy, vz, yaw_rate, frame = self._setpoint
        if frame is Frame.BODY:
            return self._rc(vx, vy, -vz, yaw_rate)
        return self._ned_rc(vx, vy, -vz, yaw_rate)

    # ================================================================= the control thread

    def _control_loop(self) -> None:
        period = 1.0 / self._p["control_hz"]
        while not self._stop.wait(period):
            try:
                self._control_tick()
            except AutopilotError as exc:
                self._ratelog.log(("tick", str(exc)), logging.WARNING, "Tello %s: %s", self.host, exc)
            except Exception:  # noqa: BLE001 - the thread must outlive a bug in one tick
                log.exception("Tello %s control tick failed", self.host)

    def _control_tick(self) -> None:
        now = self.clock()
        land = False
        with self._lock:
            self._ingest()
            rc = self._tick_rc(now)
            if self._phase is _Phase.LAND and self._land_due is not None and now >= self._land_due:
                self._land_due = None
                land = not self._silenced
        if rc is not None:
            self._send_rc(rc)
        if land:
            self._land_now()

    def _tick_rc(self, now: float) -> tuple[int, int, int, int] | None:
        """What to send this tick (lock held): streaming rc, a stop, a keepalive, or nothing."""
        if self._link_age() > self._p["link_loss_timeout"]:
            if not self._silenced:
                self._silenced = True
                log.warning("Tello %s: no state for %.1f s; stopped commanding it (it lands itself 15 s after "
                            "the last command)", self.host, self._link_age())
                return (0, 0, 0, 0) if self._in_air() else None
            return None
        if self._silenced:
            self._silenced = False
            if self._in_air() and self._phase is not _Phase.LAND:
                # The HLC has given up on this flight (LLC_DOWN is final) or will see it end: nobody
                # would command the Tello again, and our keepalives would hold it up until its battery
                # ran out. End the flight where it is.
                log.warning("Tello %s: state packets are back after a link loss in flight: landing", self.host)
                self._phase = _Phase.LAND
                self._setpoint = None
                self._climb_target = None
                self._land_due = now
                return (0, 0, 0, 0)
            log.info("Tello %s: state packets are back", self.host)
        phase = self._phase
        rc: tuple[int, int, int, int] | None = None
        if phase is _Phase.TAKEOFF and self._climb_target is not None:
            rc = self._climb_rc()
        elif phase is _Phase.RTL:
            rc = self._rtl_rc(now)
        elif phase is _Phase.GUIDED and self._setpoint is not None:
            if now - self._setpoint_time <= self._p["velocity_hold"]:
                rc = self._setpoint_rc()
            else:
                self._setpoint = None
        if rc is not None:
            self._stop_ticks = _STOP_REPEAT if any(rc) else 0
            return rc
        if self._stop_ticks > 0 and phase is not _Phase.LAND:
            self._stop_ticks -= 1
            return (0, 0, 0, 0)
        if phase is _Phase.GUIDED and self._in_air() and now - self._last_sent >= self._p["keepalive_s"]:
            return (0, 0, 0, 0)
        return None

    def _climb_rc(self) -> tuple[int, int, int, int]:
        assert self._climb_target is not None
        error = self._climb_target - self._height
        if abs(error) <= _CLIMB_TOLERANCE:
            log.info("Tello %s reached %.2f m (target %.2f m)", self.host, self._height, self._climb_target)
            self._climb_target = None
            self._phase = _Phase.GUIDED
            return (0, 0, 0, 0)
        limit = self._p["max_vertical_speed"]
        speed = max(_MIN_CLIMB_SPEED, min(limit, _CLIMB_GAIN * abs(error)))
        return self._rc(0.0, 0.0, math.copysign(speed, error), 0.0)

    def _rtl_rc(self, now: float) -> tuple[int, int, int, int]:
        tn, te = self._takeoff_point
        dn, de = tn - self._north, te - self._east
        dist = math.hypot(dn, de)
        p = self._p
        deadline = 10.0 + 3.0 * self._rtl_dist0 / p["rtl_speed"]
        reason = ""
        if dist <= p["rtl_tolerance"]:
            reason = f"at the take-off point ({dist:.2f} m)"
        elif dist > self._rtl_dist0 + _RTL_DIVERGENCE:
            reason = (f"getting farther ({dist:.1f} m, started at {self._rtl_dist0:.1f} m): check vgx_sign, "
                      "vgy_sign, velocity_frame and home_heading; landing here")
        elif now - self._rtl_start > deadline:
            reason = f"not back after {deadline:.0f} s ({dist:.1f} m to go): landing here"
        if reason:
            (log.info if dist <= p["rtl_tolerance"] else log.warning)("Tello %s RTL: %s", self.host, reason)
            self._phase = _Phase.LAND
            self._land_due = now  # the control thread lands (outside the state lock)
            return (0, 0, 0, 0)
        speed = max(_MIN_APPROACH_SPEED, min(p["rtl_speed"], _APPROACH_GAIN * dist))
        return self._ned_rc(dn / dist * speed, de / dist * speed, 0.0, 0.0)
