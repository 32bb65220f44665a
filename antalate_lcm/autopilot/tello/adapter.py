"""`TelloAutopilot`: a DJI/Ryze Tello over Wi-Fi through djitellopy (docs/design.md §7, ``tello``).

The Tello speaks the SDK text protocol: commands to UDP 8889 (most answered ``ok``/``error`` once
*done*, ``rc`` never answered), and a state line pushed to UDP 8890 about ten times a second. It
has no GPS, no arming step and no return-to-home, so this adapter supplies what the HLC expects on
top of it. The user-facing description (set-up, several Tellos, limits) is ``docs/tello.md``; the
arithmetic is in `antalate_lcm.autopilot.tello.maths`, the parameters in `.params`.

What the adapter adds, and why
------------------------------
* **Position by dead reckoning.** The state line carries ground velocities ``vgx/vgy`` (dm/s) and
  ``yaw`` (deg, 0 at power-on). They are rotated into north/east by ``home_heading`` and integrated
  (trapezoid rule, only while flying) from ``home_lat``/``home_lon``. Heading = ``home_heading +
  yaw``. Altitude is the state's ``h`` (cm, decimetre resolution) or the ``tof`` range finder.
  Signs and frame of ``vgx/vgy`` are configurable (``vgx_sign``, ``vgy_sign``, ``velocity_frame``).
* **Its own command path.** djitellopy sends an answered command and then blocks on the one reply
  list it keeps per drone, resending on a timeout (a second ``takeoff``!). The Tello's replies carry
  no id, so a late ``ok`` is taken as the answer to the next command. Here an answered command is
  sent once (djitellopy's socket, no retry) and its wait is a loop that also reads the state
  packets: a lost ``ok`` to ``takeoff`` is settled once the state shows the Tello in the air and
  holding its height, a lost ``ok`` to ``land`` once it shows it on the ground; a read (``battery?``)
  skips a stray ``ok``. ``land``, ``rtl`` and `emergency` pre-empt a command that is still waiting.
* **Link age.** The link's ``state()`` is a new object for every packet (djitellopy's receiver thread
  replaces its per-drone dict), so a new object means a new packet; it is stamped with the adapter's
  clock when first seen, read into the adapter's units by `telemetry.read`, and dead-reckoned.
* **The link** (`link.TelloLink`) is given by the caller: djitellopy's sockets by default,
  `link.MemoryLink` to a peer in this process in tests (no socket, the same adapter).
* **A control thread** at ``control_hz`` (a fixed schedule: rc goes out at that rate and no other)
  streams ``rc`` while a velocity set-point, the take-off climb or the RTL leg is active, and sends
  ``rc 0 0 0 0`` every ``keepalive_s`` whenever the Tello is in the air and not landing -- also while
  a command waits for its answer -- because a Tello lands itself 15 s after the last command.
* **Link loss.** With no state for ``link_loss_timeout`` s the thread sends one hover and then stays
  silent, so that the Tello's own 15 s failsafe lands it instead of our keepalives holding it up
  unseen. Once it must have landed (15 s after our last command, or at once if it was on the
  ground) the thread sends ``command`` once a second, which re-enters SDK mode on a Tello that
  rebooted or forgot us. When state comes back the adapter re-reads the vehicle: on the ground it is
  GROUND; in the air it hovers for ``link_back_hover`` s waiting for a command (the HLC recovering
  from LLC_DOWN) and then lands it, so a Tello nobody commands any more is not held up forever.
* **RTL** = fly back to the take-off point at ``rtl_speed`` with ``rc``, then ``land``. `rtl`
  returns once the distance is shrinking (a few seconds at most) or raises `AutopilotError` when it
  grows or does not shrink (a wrong sign convention or heading): the Tello then lands where it is,
  and the HLC reports the reason as an ``hlc_error_t``. Later failures of the leg (it grows by
  ``2 m``, or it takes far longer than it should) also land it where it is, with the reason in
  ``AutopilotState.failsafe``.
* **Take-off to an altitude.** The Tello's own ``takeoff`` stops at about 0.8 m. With
  ``takeoff_altitude_mode = "rc"`` (default) `takeoff` returns once that is done and the control
  thread climbs (or descends) with ``rc`` until `maths.climb_done`: the reading at or above the target
  (`base.altitude_reached` at fraction 1, so the HLC's ``airborne_fraction`` test holds whatever it
  is) and at most a decimetre above it. With ``"up"`` `takeoff` also sends ``up``/``down`` and returns
  only at the altitude.
* **No arming.** The motors start with ``takeoff``. `arm` checks the link, that a command is
  answered (``battery?``) and the battery; `disarm` is a no-op on the ground.

One process, several Tellos: djitellopy binds UDP 8889 and 8890 on all addresses once per process
and files replies and state packets by the sender's IP. Several Tellos are therefore several agents
of one ``antalate agent`` process, each with its own ``host``.
"""

from __future__ import annotations

import enum
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from pydantic import BaseModel

from antalate_lcm.autopilot.base import (
    AutopilotError,
    AutopilotState,
    FlightMode,
    Frame,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.autopilot.kit import LinkAge, VehicleAdapter
from antalate_lcm.autopilot.tello import maths, telemetry
from antalate_lcm.autopilot.tello.link import DjitellopyLink, TelloLink
from antalate_lcm.autopilot.tello.params import Params
from antalate_lcm.base.geo import FlatFrame, wrap_360
from antalate_lcm.base.ratelimit import RateLimitedLog

log = logging.getLogger("antalate.autopilot.tello")

_APPROACH_GAIN = 1.0  # 1/s: RTL speed per metre of remaining distance (below rtl_speed)
_MIN_APPROACH_SPEED = 0.2  # m/s
_RTL_DIVERGENCE = 2.0  # m: farther than the start distance by this much during the leg -> land here
_RTL_PROGRESS = 0.5  # m: rtl() returns once the distance shrank by this (or by half, when shorter)
_RTL_EARLY_DIVERGENCE = 0.5  # m: rtl() fails when the distance grew by this before shrinking
_GROUND_CONFIRM = 0.5  # s an in-air flag must hold before it is believed
_SETTLED = 1.0  # s of unchanged height (and zero vertical speed) that end a take-off or up/down
_LAND_RETRY = 2.0  # s between attempts when a land command failed in the air
_STOP_REPEAT = 3  # zero rc sent this many ticks in a row when motion stops (UDP may drop one)
_PROBE_PERIOD = 1.0  # s between "command" probes while the link is lost
_UP_MIN_CM, _UP_MAX_CM = 20, 500  # the SDK's range for up/down
_POLL = 0.02  # s between looks at the reply list and the state while a command waits


class _Phase(enum.Enum):
    """What the adapter is doing; the value is the mode name shown in telemetry."""

    GROUND = "GROUND"
    TAKEOFF = "TAKEOFF"  # the Tello's takeoff, then the climb to the target altitude
    GUIDED = "GUIDED"  # hovering or following velocity set-points
    RTL = "RTL"  # flying back to the take-off point
    LAND = "LAND"  # landing (a land command, or the end of an RTL)


_FLIGHT_MODES = {_Phase.RTL: FlightMode.RTL, _Phase.LAND: FlightMode.LANDING}


class _Preempted(AutopilotError):
    """A waiting command was overtaken by land, rtl or emergency."""


class TelloAutopilot(VehicleAdapter[Params, TelloLink]):
    """A Tello through djitellopy; see the module docstring for what is emulated on top of the SDK."""

    name = "tello"
    blocking = True  # takeoff/land/up wait for the Tello's answer, which comes when the move is done
    params_model: ClassVar[type[BaseModel]] = Params

    def _setup(self) -> None:
        """The constructor's ``link=`` opens the link at `connect` (`link.MemoryLink` in tests; default
        djitellopy's sockets, `_default_link`)."""
        p = self._p
        self.host: str = p.host
        self.home = FlatFrame(p.home_lat, p.home_lon)
        self._home_heading = wrap_360(p.home_heading)
        self._link: TelloLink | None = None  # once connected
        self._lock = threading.RLock()  # adapter state, shared by the HLC, control and caller threads
        self._cmd_lock = threading.RLock()  # one answered command at a time (replies carry no id)
        self._lander: threading.Thread | None = None
        self._connected = False
        self._ratelog = RateLimitedLog(log, period=10.0, clock=self.clock)
        # Telemetry from the newest state packet.
        self._raw: Mapping[str, Any] | None = None  # the dict object of the last packet (identity = packet)
        self._state_age = LinkAge(self.clock)  # heard_at: clock() when the newest packet was first seen
        self._reading = telemetry.StateReading()  # the newest packet in the adapter's units
        self._height_changed = -math.inf  # clock() of the last change of the height reading
        self._air = maths.Debounced(_GROUND_CONFIRM)  # the in-air flag, believed once it held
        # Dead reckoning (metres north/east of home).
        self._north = self._east = 0.0
        self._takeoff_point = (0.0, 0.0)
        # What the adapter is doing.
        self._phase = _Phase.GROUND
        self._pending: str | None = None  # the answered command waiting for its reply
        self._preempt = 0  # bumped by land/rtl/emergency: a waiting command gives up
        self._climb_target: float | None = None  # m; set while the rc climb is active
        self._setpoint: tuple[float, float, float, float, Frame] | None = None  # vx, vy, vz, yaw_rate, frame
        self._setpoint_time = 0.0
        self._rtl_start = 0.0
        self._rtl_dist0 = 0.0
        self._failsafe = ""  # why the adapter is landing on its own (a failed RTL, nobody commanding)
        self._land_due: float | None = None  # clock() at which the control thread (re)tries land
        self._last_sent = -math.inf  # clock() of the last datagram sent to the Tello
        self._stop_ticks = 0  # zero rc still to send after motion stopped
        self._silenced = False  # link lost: no more commands until state comes back
        self._lost_in_air = False  # the Tello was flying when the link was lost
        self._last_probe = -math.inf
        self._unattended_until: float | None = None  # after a link loss: land unless commanded by then
        self._space_lock = threading.Lock()  # one non-rc datagram at a time, spaced (`_spaced`)
        self._quiet_since = -math.inf  # clock() of the last non-rc datagram sent or answer received
        #: (command, deadline): an answer still owed by a command settled by the state (a take-off whose
        #: "ok" is late or lost); the next control command waits for it, so it cannot pass for its own
        self._owed: tuple[str, float] | None = None
        self._sent_at = -math.inf  # clock() when the waiting command went out
        self._units = maths.VelocityUnitCheck()

    def _default_link(self, params: Params) -> TelloLink:
        """djitellopy's sockets to ``host``."""
        return DjitellopyLink(params)

    # ================================================================= the Autopilot contract

    def connect(self) -> None:
        if self._connected:
            return
        link = self._opener(self._p)
        link.open()
        self._link = link
        try:
            self._open(link)
        except BaseException:
            self._release()
            raise
        self._connected = True
        self._workers.start((self._control_loop, f"tello-{self.host}"))
        log.info(
            "Tello %s connected: battery %s%%, %s",
            self.host,
            self._reading.battery,
            "flying" if self._phase is not _Phase.GROUND else "on the ground",
        )

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            self._preempt += 1
        self._workers.halt()
        if self._link is not None and self._connected:
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
        answer = self._exchange("battery?", self._p.command_timeout)
        try:
            battery = float(answer)
        except ValueError:
            raise AutopilotError(
                f"arm: the Tello at {self.host} did not answer 'battery?' ({answer!r})"
            ) from None
        if battery <= self._p.min_battery:
            log.warning("arm refused: battery %.0f%% <= min_battery %g%%", battery, self._p.min_battery)
            return False
        return True

    def disarm(self) -> None:
        self._require_connected("disarm")
        with self._lock:
            if self._in_air():
                raise AutopilotError(
                    "disarm refused: the Tello is flying (its only disarm, 'emergency', "
                    "cuts the motors in the air)"
                )

    def takeoff(self, alt: float) -> None:
        self._require_link("takeoff")
        check_takeoff_altitude(alt)
        with self._lock:
            if self._phase is not _Phase.GROUND or self._in_air():
                raise AutopilotError(
                    f"takeoff refused: already {self._phase.value.lower()} at {self._reading.height:.1f} m"
                )
            self._commanded()
            self._phase = _Phase.TAKEOFF
            self._takeoff_point = (self._north, self._east)
            self._setpoint = None
            self._climb_target = None
            self._failsafe = ""
            self._owed = None
            sent = self.clock()
        try:
            answer = self._exchange(
                "takeoff", self._p.takeoff_timeout, settled=self._move_settled, done_in_air=True
            )
        except _Preempted:
            raise AutopilotError("takeoff interrupted (land, rtl or emergency)") from None
        except AutopilotError:
            with self._lock:
                if self._phase is _Phase.TAKEOFF:
                    self._phase = _Phase.GUIDED if self._in_air() else _Phase.GROUND
            raise
        if answer not in ("ok", ""):
            with self._lock:
                if self._phase is _Phase.TAKEOFF:
                    self._phase = _Phase.GUIDED if self._in_air() else _Phase.GROUND
            raise AutopilotError(f"the Tello at {self.host} refused 'takeoff': {answer!r}")
        with self._lock:
            self._air.reset(True)  # it said so (or the packets did): no half second of doubt
            if not answer:  # its "ok" may still come (DJITelloPy #31: > 7 s), or was lost
                self._owed = ("takeoff", sent + self._p.takeoff_timeout)
        if not answer:
            log.warning(
                "Tello %s: no answer to 'takeoff', but the state shows it up at %.1f m: going on",
                self.host,
                self._reading.height,
            )
        if self._p.takeoff_altitude_mode == "up":
            try:
                self._climb_with_up(alt)
            except _Preempted:
                raise AutopilotError("climb interrupted (land, rtl or emergency)") from None
        else:
            self._wait_fresh_state()  # the height when "ok" came, not from a packet sent mid-climb
        with self._lock:
            if self._phase is _Phase.TAKEOFF:
                if maths.climb_done(self._reading.height, alt):
                    self._phase = _Phase.GUIDED
                else:
                    self._climb_target = alt  # the control thread takes it from here

    def land(self) -> None:
        self._require_connected("land")
        with self._lock:
            self._commanded()
            self._setpoint = None
            self._climb_target = None
            self._preempt += 1  # a waiting takeoff/up gives up at once
            self._owed = None  # a landing supersedes a take-off still running
            if self._phase is _Phase.GROUND and not self._in_air():
                return  # nothing to land
            self._phase = _Phase.LAND
            self._land_due = None
        self._send_rc((0, 0, 0, 0))
        self._land_now()

    def rtl(self) -> None:
        self._require_link("rtl")
        with self._lock:
            self._commanded()
            if not self._in_air() and self._phase in (_Phase.GROUND, _Phase.TAKEOFF):
                return  # on the ground there is nowhere to return from
            if self._phase in (_Phase.RTL, _Phase.LAND):
                return  # already on the way (or down)
            self._preempt += 1
            self._setpoint = None
            self._climb_target = None
            self._failsafe = ""
            if self._units.problem:
                # home is where dead reckoning says, and it is not to be believed: land here
                reason = f"dead reckoning unreliable ({self._units.problem}); landing here"
                self._rtl_abort(reason)
                raise AutopilotError(reason)
            self._phase = _Phase.RTL
            self._rtl_start = self.clock()
            tn, te = self._takeoff_point
            self._rtl_dist0 = dist0 = math.hypot(tn - self._north, te - self._east)
            log.info("Tello %s RTL: %.1f m to the take-off point", self.host, dist0)
        self._verify_rtl(dist0)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        check_velocity(vx, vy, vz, yaw_rate)
        self._require_link("set_velocity")
        with self._lock:
            self._ingest()
            if self._phase is _Phase.TAKEOFF and self._climb_target is not None:
                self._climb_target = None  # the caller takes over from the climb
                self._phase = _Phase.GUIDED
            if self._phase is not _Phase.GUIDED:
                return  # like ArduCopter: velocity targets are ignored outside guided flight
            self._commanded()
            # Streamed by the control thread on its schedule: sending here too made the rc rate
            # control_hz plus the HLC's command rate.
            self._setpoint = (vx, vy, vz, yaw_rate, Frame(frame))
            self._setpoint_time = self.clock()

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
                link_age=self._state_age(),
                lat=lat,
                lon=lon,
                alt=self._reading.height,
                heading=self._heading(),
                vn=self._reading.vn,
                ve=self._reading.ve,
                vd=self._reading.vd,
                battery=self._reading.battery,
                armed=in_air,  # a Tello's motors run exactly while it flies
                in_air=in_air,
                autonomous=True,  # no pilot radio: always under computer control
                mode=self._phase.value,
                flight_mode=_FLIGHT_MODES.get(self._phase, FlightMode.GUIDED),
                failsafe=self._failsafe if self._phase is _Phase.LAND else "",
            )

    # ================================================================= extras (tests, tools)

    def emergency(self) -> None:
        """Stop the motors at once (the Tello drops): pre-empts any command still waiting."""
        self._require_connected("emergency")
        with self._lock:
            self._preempt += 1
            self._setpoint = None
            self._climb_target = None
            self._phase = _Phase.GROUND
            self._air.reset(False)  # it drops: not "flying though we did not take off"
            self._land_due = None
            self._owed = None
        # never answered (SDK guide; djitellopy sends it without waiting): nothing to wait for but the
        # command spacing, without which the Tello would not hear it
        self._send_raw("emergency")
        log.warning("Tello %s: emergency (motors stopped)", self.host)

    @property
    def position_ne(self) -> tuple[float, float]:
        """Dead-reckoned metres north/east of home (for tests and tools)."""
        with self._lock:
            return self._north, self._east

    @property
    def dead_reckoning_problem(self) -> str:
        """Why the state's velocities cannot be dead-reckoned (`maths.VelocityUnitCheck`); "" while none."""
        with self._lock:
            return self._units.problem

    @property
    def takeoff_point(self) -> tuple[float, float]:
        """Where the last take-off began, metres north/east of home: the RTL's destination."""
        with self._lock:
            return self._takeoff_point

    # ================================================================= link and commands

    def _open(self, link: TelloLink) -> None:
        """Enter SDK mode and wait for state on the open `link` (connect's I/O).

        This is djitellopy's ``Tello.connect()`` done by hand: its own waits 3 x 7 s for an answer
        and 1 s for state, fixed; a dead host must fail in ``command_timeout`` x ``retry_count`` s, and
        each failure must say what to check.
        """
        p = self._p
        answer = ""
        for _ in range(p.retry_count):
            try:
                answer = self._exchange("command", p.command_timeout, preemptible=False)
            except AutopilotError as exc:
                answer = str(exc)
                continue
            if answer == "ok":
                break
        else:
            raise AutopilotError(
                f"no answer from the Tello at {link.where} to 'command' "
                f"({p.retry_count} x {p.command_timeout:g} s): is it on, and is this machine on its "
                f"Wi-Fi (or it on yours, in station mode)? ({answer})"
            )
        deadline = self.clock() + p.state_timeout
        while True:
            with self._lock:
                self._ingest()
                if self._state_age.heard_at is not None:
                    self._air.reset(self._in_air())
                    self._phase = _Phase.GUIDED if self._in_air() else _Phase.GROUND
                    self._takeoff_point = (self._north, self._east)
                    return
            if self.clock() >= deadline:
                raise AutopilotError(
                    f"the Tello at {self.host} entered SDK mode but sent no state packet to "
                    f"{link.state_where} within {p.state_timeout:g} s (a firewall, or another "
                    "program bound to that port?)"
                )
            time.sleep(_POLL)

    def _release(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            link.close()

    def _require_connected(self, what: str) -> None:
        if not self._connected or self._link is None:
            raise AutopilotError(f"{what}: not connected to the Tello at {self.host}")

    def _require_link(self, what: str) -> None:
        self._require_connected(what)
        with self._lock:
            self._ingest()
            age = self._state_age()
        if age > self._p.link_loss_timeout:
            raise AutopilotError(
                f"{what}: no state from the Tello at {self.host} for {age:.1f} s (link lost)"
            )

    def _commanded(self) -> None:
        """The HLC commanded the Tello (lock held): someone is flying it after a link loss."""
        self._unattended_until = None

    def _replies(self) -> list[bytes]:
        link = self._link
        if link is None:
            raise AutopilotError(f"the link to the Tello at {self.host} is closed")
        return link.replies()

    def _send_raw(self, text: str) -> None:
        """One datagram to the Tello through the link (no retry); any but ``rc`` spaced (`_spaced`)."""
        link = self._link
        if link is None:
            raise AutopilotError(f"{text!r}: not connected to the Tello at {self.host}")
        try:
            if text.startswith("rc "):
                link.send(text)
            else:
                with self._space_lock:
                    self._await_spacing()
                    link.send(text)
                    self._quiet_since = self.clock()
        except OSError as exc:
            raise AutopilotError(f"{text!r} to the Tello at {self.host} failed: {exc!r}") from exc
        finally:
            self._last_sent = self.clock()

    def _await_spacing(self) -> None:
        """Sleep until ``command_spacing`` has passed since the last non-rc datagram or answer.

        A Tello ignores a command that comes too soon after the previous one or its answer, without a
        reply (djitellopy waits ``Tello.TIME_BTW_COMMANDS`` = 0.1 s after each answer: "Commands very
        consecutive makes the drone not respond to them"). ``rc`` is exempt, as in djitellopy
        (``TIME_BTW_RC_CONTROL_COMMANDS`` = 0.001 s)."""
        wait = self._quiet_since + self._p.command_spacing - self.clock()
        if wait > 0:
            time.sleep(wait)

    def _heard(self) -> None:
        """An answer came: the next command is spaced from now."""
        self._quiet_since = max(self._quiet_since, self.clock())

    def _settle_owed(self, replies: list[bytes], generation: int) -> None:
        """Wait for an answer a command settled by the state still owes, before a control command.

        Replies carry no id: a take-off's late "ok" arriving after the next command was sent would pass
        for that command's answer (and the Tello, still in its take-off, refuses a move with "error").
        Ends at the owed answer, its deadline, or a pre-emption.
        """
        while (owed := self._owed) is not None:  # land/emergency clear it from other threads
            what, deadline = owed
            if replies:
                answer = replies.pop(0).decode("utf-8", "replace").strip()
                self._heard()
                log.info("Tello %s: the late answer to %r came: %r", self.host, what, answer)
                self._owed = None
                return
            with self._lock:
                self._ingest()
                if self._preempt != generation:
                    raise _Preempted(f"pre-empted while waiting for the answer to {what!r}")
            if self.clock() >= deadline:
                log.info("Tello %s: no answer to %r came (lost)", self.host, what)
                self._owed = None
                return
            if self._stop.is_set():
                raise AutopilotError("the adapter is closing")
            time.sleep(_POLL)

    def _exchange(
        self,
        text: str,
        timeout: float,
        *,
        settled: Callable[[], bool] | None = None,
        done_in_air: bool = False,
        preemptible: bool = True,
    ) -> str:
        """Send an answered command once and wait for its answer; ``""`` when `settled` said done first.

        `settled` (called with the state lock held, after each state packet is taken in) lets the state
        packets answer for a reply that was lost. A timeout raises `AutopilotError`, except that with
        `done_in_air` a Tello seen flying at the deadline counts as done (a take-off whose ``ok`` was lost
        while the height kept wandering). land/rtl/emergency raise `_Preempted` in a `preemptible` wait.
        """
        with self._lock:
            generation = self._preempt
        with self._cmd_lock:
            with self._lock:
                if preemptible and self._preempt != generation:
                    raise _Preempted(f"{text!r} pre-empted before it was sent")
                self._pending = text
            try:
                replies = self._replies()
                if preemptible and not text.endswith("?"):
                    self._settle_owed(replies, generation)  # (a read skips a stray "ok" itself)
                with self._space_lock:
                    self._await_spacing()
                if replies:
                    self._heard()
                replies.clear()  # late replies to earlier commands, which would pass for this one's
                self._send_raw(text)
                with self._lock:
                    self._sent_at = self.clock()
                deadline = self.clock() + timeout
                while True:
                    while replies:
                        answer = replies.pop(0).decode("utf-8", "replace").strip()
                        self._heard()
                        if text.endswith("?") and answer.lower() == "ok":
                            continue  # a read is never answered "ok": a late reply to a control command
                        return answer
                    with self._lock:
                        self._ingest()
                        if preemptible and self._preempt != generation:
                            raise _Preempted(f"{text!r} pre-empted")
                        if settled is not None and settled():
                            return ""
                        if self.clock() >= deadline:
                            if done_in_air and self._air.value:
                                return ""
                            raise AutopilotError(
                                f"the Tello at {self.host} did not answer {text!r} within {timeout:g} s"
                            )
                    if self._stop.is_set():
                        raise AutopilotError(f"{text!r}: the adapter is closing")
                    time.sleep(_POLL)
            finally:
                with self._lock:
                    self._pending = None

    def _move_settled(self) -> bool:
        """A take-off or up/down whose answer was lost is over (lock held): flying, height steady.

        Timed from when the command went out (`_sent_at`), not from the call: a wait for an owed
        answer may come first, hovering, and that hover is not this move settling.
        """
        now = self.clock()
        return (
            self._air.value
            and now - self._sent_at >= _SETTLED
            and now - self._height_changed >= _SETTLED
            and abs(self._reading.vd) < 0.05
        )

    def _landed(self) -> bool:
        """The state packets have shown the Tello on the ground for `_GROUND_CONFIRM` (lock held)."""
        return not self._air.value and not self._in_air()

    def _send_rc(self, rc: tuple[int, int, int, int]) -> None:
        """Send ``rc`` (never answered: it cannot be mistaken for a reply)."""
        try:
            self._send_raw("rc {} {} {} {}".format(*rc))
        except AutopilotError as exc:  # a failed send is a lost datagram, not a crash
            self._ratelog.log(("rc",), logging.WARNING, "Tello %s: rc not sent: %s", self.host, exc)

    def _land_now(self) -> None:
        """Send ``land`` unless the Tello is already down; settled by its answer or by the state packets.

        The check is made holding the command lock, so when the HLC's `land` and the end of an RTL
        meet, the second finds the Tello on the ground instead of sending a second ``land``. On a
        failure in the air the control thread retries.
        """
        with self._cmd_lock:
            with self._lock:
                self._ingest()
                if self._phase is not _Phase.LAND:
                    return
                if self._landed():
                    self._phase = _Phase.GROUND
                    return
            try:
                answer = self._exchange(
                    "land", self._p.takeoff_timeout, settled=self._landed, preemptible=False
                )
            except AutopilotError:
                answer = "no answer"
        with self._lock:
            if self._phase is not _Phase.LAND:
                return  # emergency, or the Tello was seen on the ground meanwhile
            if answer == "ok" and not self._in_air():
                self._air.reset(False)  # down, by its answer and the newest packet
            if answer == "ok" or self._landed():
                # "ok" comes once it is down; the next packets say so, and until they have the HLC
                # sees the landing still in progress (state() keeps in_air while LAND). Should they
                # never say so (an "ok" that answered something else), land is sent again.
                self._land_due = self.clock() + 2.0 * _LAND_RETRY
                if self._landed():
                    self._phase = _Phase.GROUND
                return
            self._land_due = self.clock() + _LAND_RETRY
        raise AutopilotError(
            f"the Tello at {self.host} did not land ({answer!r}); retrying every {_LAND_RETRY:g} s"
        )

    def _land_in_background(self) -> None:
        """Land from a thread of its own, so the control thread keeps its rc schedule."""
        if self._lander is not None and self._lander.is_alive():
            return

        def run() -> None:
            try:
                self._land_now()
            except AutopilotError as exc:
                self._ratelog.log(("land", str(exc)), logging.WARNING, "Tello %s: %s", self.host, exc)

        self._lander = threading.Thread(target=run, name=f"tello-land-{self.host}", daemon=True)
        self._lander.start()

    def _verify_rtl(self, dist0: float) -> None:
        """Wait until the RTL leg is seen closing in; raise (and land here) when it is not."""
        p = self._p
        progress = min(_RTL_PROGRESS, dist0 / 2.0)
        deadline = self.clock() + 1.0 + 3.0 * _RTL_PROGRESS / p.rtl_speed
        while True:
            with self._lock:
                self._ingest()
                if self._phase is not _Phase.RTL:
                    if self._failsafe:  # the control thread gave up first (the HLC prefixes "RTL failed")
                        raise AutopilotError(self._failsafe.removeprefix("RTL failed: "))
                    return  # arrived (landing) or overtaken by a land/emergency
                tn, te = self._takeoff_point
                dist = math.hypot(tn - self._north, te - self._east)
                if dist <= p.rtl_tolerance or dist <= dist0 - progress:
                    return
                reason = ""
                if dist > dist0 + _RTL_EARLY_DIVERGENCE:
                    reason = (
                        f"getting farther ({dist:.1f} m, started at {dist0:.1f} m): check vgx_sign, "
                        "vgy_sign, velocity_frame and home_heading; landing here"
                    )
                elif self.clock() >= deadline:
                    reason = (
                        f"not getting closer ({dist:.1f} m, started at {dist0:.1f} m) after "
                        f"{deadline - self._rtl_start:.0f} s; landing here"
                    )
                if reason:
                    self._rtl_abort(reason)
                    break
            time.sleep(0.05)
        raise AutopilotError(reason)  # the HLC reports "autopilot RTL failed: <reason>"

    def _rtl_abort(self, reason: str) -> None:
        """End the RTL where the Tello is (lock held): land here, and say why."""
        log.warning("Tello %s RTL: %s", self.host, reason)
        self._failsafe = f"RTL failed: {reason}"
        self._phase = _Phase.LAND
        self._land_due = self.clock()  # the control thread lands (outside the state lock)

    def _climb_with_up(self, alt: float) -> None:
        """``takeoff_altitude_mode = "up"``: blocking up/down until the climb is done (or 20 cm short)."""
        for _ in range(4):
            self._wait_fresh_state()
            with self._lock:
                delta = alt + maths.CLIMB_BAND / 2.0 - self._reading.height
                if maths.climb_done(self._reading.height, alt):
                    return
            cm = max(_UP_MIN_CM, round(abs(delta) * 100))
            answer = self._exchange(
                f"{'up' if delta > 0 else 'down'} {min(cm, _UP_MAX_CM)}",
                self._p.takeoff_timeout,
                settled=self._move_settled,
                done_in_air=True,
            )
            if answer not in ("ok", ""):
                raise AutopilotError(f"the Tello at {self.host} refused the climb: {answer!r}")

    def _wait_fresh_state(self, timeout: float = 0.5) -> None:
        """Until a state packet newer than the call arrives (or `timeout` s, all on the adapter's clock)."""
        start = self.clock()
        while self.clock() - start < timeout:
            with self._lock:
                self._ingest()
                heard_at = self._state_age.heard_at
                if heard_at is not None and heard_at > start:
                    return
            time.sleep(_POLL)

    # ================================================================= state packets, dead reckoning

    def _ingest(self) -> None:
        """Take in the newest state packet, if the link received one since the last call (lock held).

        Three steps: the packet as a reading (`telemetry.read`, pure), the dead-reckoned position
        (`maths.dead_reckon`, pure), then what the reading means for the adapter (a link back, a
        landing nobody commanded: `_link_back`, `_track_ground`).
        """
        link = self._link
        raw = link.state() if link is not None else None
        if raw is None or raw is self._raw:
            return
        now = self.clock()
        self._raw = raw
        previous, before = self._state_age.heard_at, self._reading
        self._state_age.heard(now)
        self._reading = telemetry.read(raw, self._p, self._home_heading, before)
        if self._reading.height != before.height:
            self._height_changed = now
        r = self._reading
        if self._p.velocity_unit_check and self._units.update(r.height, r.vd, r.vn, r.ve, now):
            u = self._units
            why = f"dead reckoning unreliable: {u.problem}" if u.problem else u.unchecked
            log.warning("Tello %s: %s", self.host, why)
        if previous is not None and self._in_air():
            self._north, self._east = maths.dead_reckon(
                self._north,
                self._east,
                (before.vn, before.ve),
                (self._reading.vn, self._reading.ve),
                now - previous,
            )
        if self._silenced:
            # Whoever sees the first packet after a loss re-reads the vehicle, before anyone can act on
            # the fresh link: the HLC's state() may see it first and command an RTL within the same
            # tick, which a later re-read by the control thread would undo.
            self._link_back(now)
        self._air.update(self._in_air(), now)
        self._track_ground()

    def _track_ground(self) -> None:
        """Notice a Tello that landed (or took off) without us: its own failsafes, another client.

        Not while a command waits for its answer (that wait settles its own outcome) nor while the
        link is lost (the control thread re-reads the vehicle when it is back).
        """
        if self._pending is not None or self._silenced:
            return
        if self._phase is not _Phase.GROUND and not self._air.value:
            if self._phase is not _Phase.LAND:
                log.warning(
                    "Tello %s is on the ground (landed by itself: battery, or 15 s without a command?)",
                    self.host,
                )
            self._to_ground()
        elif self._phase is _Phase.GROUND and self._air.value:
            log.warning(
                "Tello %s is flying though we did not take off: hovering under our control", self.host
            )
            self._phase = _Phase.GUIDED

    def _to_ground(self) -> None:
        self._phase = _Phase.GROUND
        self._setpoint = None
        self._climb_target = None
        self._land_due = None
        self._unattended_until = None

    def _in_air(self) -> bool:
        """What the newest packet says (height above zero); `state` adds the landing in progress."""
        return self._reading.h_cm > 0

    def _heading(self) -> float:
        return wrap_360(self._home_heading + self._reading.yaw)

    # ================================================================= rc

    def _rc(self, fwd: float, right: float, up: float, yaw_rate: float) -> tuple[int, int, int, int]:
        p = self._p
        return maths.rc_sticks(
            fwd,
            right,
            up,
            yaw_rate,
            max_speed=p.max_speed,
            max_vertical_speed=p.max_vertical_speed,
            max_yaw_rate=p.max_yaw_rate,
        )

    def _ned_rc(self, vn: float, ve: float, up: float, yaw_rate: float) -> tuple[int, int, int, int]:
        fwd, right = maths.ne_to_body(vn, ve, self._heading())
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
        """Tick at ``control_hz`` on a fixed schedule (a late tick does not delay the next ones)."""
        period = 1.0 / self._p.control_hz
        due = self.clock()
        while True:
            due += period
            delay = due - self.clock()
            if delay < -period:  # fell behind (a stalled machine): restart the schedule, no burst
                due = self.clock()
                delay = 0.0
            if self._stop.wait(max(0.0, delay)):
                return
            try:
                self._control_tick()
            except AutopilotError as exc:
                self._ratelog.log(("tick", str(exc)), logging.WARNING, "Tello %s: %s", self.host, exc)
            except Exception:  # noqa: BLE001 - the thread must outlive a bug in one tick
                log.exception("Tello %s control tick failed", self.host)

    def _control_tick(self) -> None:
        now = self.clock()
        land = probe = False
        with self._lock:
            self._ingest()
            rc = self._tick_rc(now)
            if self._silenced:
                probe = self._probe_due(now)
            elif self._phase is _Phase.LAND and self._land_due is not None and now >= self._land_due:
                self._land_due = None
                land = True
        if rc is not None:
            self._send_rc(rc)
        if probe:
            self._probe()
        if land:
            self._land_in_background()

    def _probe_due(self, now: float) -> bool:
        """While the link is lost: time to send ``command``? (lock held)

        Not while the Tello may still be flying on its own: a probe that reaches it resets its 15 s
        auto-landing, and our keepalives are what the silence is there to stop.
        """
        if now - self._last_probe < _PROBE_PERIOD or self._pending is not None:
            return False  # (its "ok" would pass for the waiting command's answer)
        if self._lost_in_air and now - self._last_sent < self._p.autoland_s:
            return False
        self._last_probe = now
        return True

    def _probe(self) -> None:
        """``command`` again: a Tello that rebooted or dropped us sends state only in SDK mode."""
        link = self._link
        if link is None:
            return
        try:
            with self._space_lock:
                self._await_spacing()
                link.send("command")  # the "ok" is dropped by the next exchange
                self._quiet_since = self.clock()
        except OSError as exc:
            self._ratelog.log(("probe",), logging.WARNING, "Tello %s: probe not sent: %s", self.host, exc)

    def _tick_rc(self, now: float) -> tuple[int, int, int, int] | None:
        """What to send this tick (lock held): streaming rc, a stop, a keepalive, or nothing."""
        p = self._p
        if self._state_age() > p.link_loss_timeout:
            if not self._silenced:
                self._silenced = True
                self._lost_in_air = self._in_air() or self._phase is not _Phase.GROUND
                self._last_probe = now
                log.warning(
                    "Tello %s: no state for %.1f s; stopped commanding it (it lands itself 15 s after "
                    "the last command)",
                    self.host,
                    self._state_age(),
                )
                return (0, 0, 0, 0) if self._lost_in_air else None
            return None
        if (
            self._unattended_until is not None
            and now >= self._unattended_until
            and self._phase is _Phase.GUIDED
        ):
            self._unattended_until = None
            self._failsafe = (
                f"nobody commanded the Tello for {p.link_back_hover:g} s after a link loss: landing"
            )
            log.warning("Tello %s: %s", self.host, self._failsafe)
            self._phase = _Phase.LAND
            self._setpoint = None
            self._land_due = now
            return (0, 0, 0, 0)
        phase = self._phase
        rc: tuple[int, int, int, int] | None = None
        if phase is _Phase.TAKEOFF and self._climb_target is not None:
            rc = self._climb_rc()
        elif phase is _Phase.RTL:
            rc = self._rtl_rc(now)
        elif phase is _Phase.GUIDED and self._setpoint is not None:
            if now - self._setpoint_time <= p.velocity_hold:
                rc = self._setpoint_rc()
            else:
                self._setpoint = None
        if rc is not None:
            self._stop_ticks = _STOP_REPEAT if any(rc) else 0
            return rc
        if self._stop_ticks > 0 and phase is not _Phase.LAND:
            self._stop_ticks -= 1
            return (0, 0, 0, 0)
        if phase is not _Phase.LAND and self._in_air() and now - self._last_sent >= p.keepalive_s:
            return (0, 0, 0, 0)  # also while a takeoff or up waits for its answer
        return None

    def _link_back(self, now: float) -> None:
        """State packets are back after a link loss: re-read the vehicle (lock held)."""
        self._silenced = False
        self._air.reset(self._in_air())
        if not self._in_air():
            if self._phase is not _Phase.GROUND:
                log.warning("Tello %s: state is back; it landed during the link loss", self.host)
            else:
                log.info("Tello %s: state is back", self.host)
            self._to_ground()
            return
        if self._phase is _Phase.LAND:
            log.warning("Tello %s: state is back; still landing", self.host)
            self._land_due = now
            return
        if self._phase is _Phase.RTL:
            log.warning("Tello %s: state is back; going on home (dead reckoning missed the loss)", self.host)
            return
        self._phase = _Phase.GUIDED
        self._setpoint = None
        self._climb_target = None
        self._unattended_until = now + self._p.link_back_hover
        log.warning(
            "Tello %s: state is back with the Tello in the air at %.1f m: hovering; it lands in "
            "%g s unless commanded",
            self.host,
            self._reading.height,
            self._p.link_back_hover,
        )

    def _climb_rc(self) -> tuple[int, int, int, int]:
        assert self._climb_target is not None
        speed = maths.climb_speed(self._reading.height, self._climb_target, self._p.max_vertical_speed)
        if speed == 0.0:
            log.info(
                "Tello %s reached %.2f m (target %.2f m)", self.host, self._reading.height, self._climb_target
            )
            self._climb_target = None
            self._phase = _Phase.GUIDED
            return (0, 0, 0, 0)
        return self._rc(0.0, 0.0, speed, 0.0)

    def _rtl_rc(self, now: float) -> tuple[int, int, int, int]:
        p = self._p
        vn, ve, dist = maths.rtl_leg(
            self._north,
            self._east,
            self._takeoff_point,
            speed=p.rtl_speed,
            gain=_APPROACH_GAIN,
            min_speed=_MIN_APPROACH_SPEED,
        )
        deadline = 10.0 + 3.0 * self._rtl_dist0 / p.rtl_speed
        if dist <= p.rtl_tolerance:
            log.info("Tello %s RTL: at the take-off point (%.2f m): landing", self.host, dist)
            self._phase = _Phase.LAND
            self._land_due = now  # the control thread lands (outside the state lock)
            return (0, 0, 0, 0)
        if dist > self._rtl_dist0 + _RTL_DIVERGENCE:
            self._rtl_abort(
                f"getting farther ({dist:.1f} m, started at {self._rtl_dist0:.1f} m): check "
                "vgx_sign, vgy_sign, velocity_frame and home_heading; landing here"
            )
            return (0, 0, 0, 0)
        if now - self._rtl_start > deadline:
            self._rtl_abort(f"not back after {deadline:.0f} s ({dist:.1f} m to go): landing here")
            return (0, 0, 0, 0)
        return self._ned_rc(vn, ve, 0.0, 0.0)
