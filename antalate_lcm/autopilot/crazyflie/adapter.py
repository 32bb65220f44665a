"""The Crazyflie adapter's I/O: cflib's link, log blocks, high-level commander and streamed set-points.

What the adapter does on top of cflib, and why (docs/crazyflie.md has the operator's view):

* **State** comes from three log blocks (`telemetry.LOG_BLOCKS`): the state estimator's pose and
  velocity, yaw, battery (``pm.vbat``, ``pm.batteryLevel``, ``pm.state``), the supervisor's bitfield
  (armed, flying, tumbled, locked) and the Kalman position variances. The link age is the time since
  the last packet of any kind (log data, or the answers to cflib's 10 Hz latency pings).
* **Commands**: take-off, landing and the return flight go through the high-level commander, whose
  trajectories run on board and survive a lost link; MISSION velocities are streamed generic
  set-points at ``control_hz`` (the firmware levels the vehicle 0.5 s after the last one and stops its
  motors after 2 s). Leaving the stream for the high-level commander is cflib's documented switch,
  ``notify_setpoint_stop`` then a high-level command -- but never the notification alone: a stream
  stops the firmware's planner, and a stopped planner answers the notification with the null
  set-point, motors off, until a high-level command comes (crazyflie-firmware 2026.08
  crtp_commander_high_level.c ``crtpCommanderHighLevelGetSetpoint``, commander.c, PR #1298). So the
  switch is *command, notify, command* (`_switch`): whichever of the two commands arrives, the
  planner has a trajectory when the priority drops. The firmware answers every high-level packet
  (crtp_commander_high_level.c ``crtpCommanderHighLevelTask``); until the command that set the mode
  is answered, the switch is resent every ``_HL_RESEND_S`` -- also into a stale or closed link,
  so it lands as soon as the link carries it. A zero velocity, a velocity not renewed for
  ``velocity_hold`` and a link silent for ``link_stale_after`` all hand the vehicle back to the
  high-level commander holding where it is. If the switch cannot get through at all, the firmware's
  watchdog takes over: 0.5 s after the last set-point it levels the vehicle but keeps its vertical
  velocity (a climb goes on), 2 s after it stops the motors and locks (supervisor.c).
* **Link loss in the air**: after ``link_loss_land`` s the adapter sends landings blindly (a radio
  link that drops most packets still delivers some); the state then says LANDING with the failsafe
  "link lost". A Crazyflie has no link-loss failsafe of its own under the high-level commander.
* **Arming** is refused, with the reason in ``last_refusal`` (and so in ``hlc_error_t``), while the
  supervisor is locked, crashed or tumbled, the estimator has not converged, ``pm.state`` says the
  battery is low, or ``pm.vbat`` is at or below ``low_voltage`` (the firmware says lowPower only
  5 s later: pm_stm32f4.c). A CF2.x arms itself (Kconfig ``MOTORS_REQUIRE_ARMING`` defaults to n;
  supervisor.c ``AUTO_ARMING``: at power-on, after a disarm, after the landed timeout), so the
  adapter's own flag decides what the HLC sees: a vehicle on the ground reads disarmed until
  `arm` and again after a landing, and `takeoff` refuses without `arm`, whatever the supervisor
  says.
* **Critical battery in the air**: ``pm.vbat`` below ``critical_voltage`` for
  ``critical_land_after`` s lands the vehicle where it is (failsafe "battery critical"): a firmware
  built with ``CONFIG_PM_AUTO_SHUTDOWN`` powers off 5 s after that voltage once in lowPower
  (pm_stm32f4.c), and even without it the LiPo is empty.
* **Shutdown in the air**: `close` sends an emergency stop (motors off) before closing the link:
  nothing would command the vehicle any more (under the high-level commander it would hover until its
  battery is empty). Every other close -- a failed connection or reconnection -- avoids cflib's
  parting zero-thrust set-point, which would drop a flying Crazyflie (`_close_quietly`).
* **cflib closing the link**: its radio driver gives up after 100 un-acknowledged packets in a row
  ("Too many packets lost", cflib 0.1.34 crtp/radiodriver.py ``_nr_of_retries``) and closes the
  link for good; the adapter reopens it every ``_RECONNECT_S`` until the Crazyflie answers, so a
  radio outage is the HLC's recoverable LLC_DOWN, not the end of the agent. Meanwhile the control
  loop keeps its timers: a stream is turned into a hold and ``link_loss_land`` into a landing, each
  sent the moment the link is open again (a Crazyflie under the high-level commander hovers on
  its own meanwhile; one that was streaming has been stopped by the watchdog).
* Several adapters in one process on one Crazyradio share it through cflib's radio manager, as
  cflib's ``Swarm`` does.
"""

from __future__ import annotations

import logging
import math
import threading
import time
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
from antalate_lcm.autopilot.crazyflie.frames import LocalFrame
from antalate_lcm.autopilot.crazyflie.params import Params
from antalate_lcm.autopilot.crazyflie.setpoints import (
    SetPoint,
    build_setpoint,
    goto_duration,
    is_zero,
    next_height,
    takeoff_duration,
)
from antalate_lcm.autopilot.crazyflie.telemetry import (
    LOG_BLOCKS,
    Reading,
    apply_log,
    battery_warning,
    estimator_problem,
)
from antalate_lcm.autopilot.kit import LinkAge, VehicleAdapter

log = logging.getLogger("antalate.autopilot.crazyflie")

CFLIB_MISSING = (
    "the crazyflie autopilot needs Bitcraze's cflib, which is not installed: "
    "pip install 'antalate[crazyflie]'"
)

_RECONNECT_S = 2.0  # s between attempts to reopen a link cflib closed
_HL_RESEND_S = 0.3  # s without the firmware's answer to a high-level command before it is resent
#: cflib's high-level commander command bytes (crtp_commander_high_level.c TrajectoryCommand_e)
_HL_TAKEOFF, _HL_LAND, _HL_GOTO = 7, 8, 12
_HL_PORT = 8  # CRTP_PORT_SETPOINT_HL

_drivers_lock = threading.Lock()
_drivers_ready = False

# What the adapter is doing; the flight mode the HLC sees follows from it.
IDLE, TAKEOFF, HOLD, STREAM, LAND, RTL_GO, RTL_LAND = (
    "IDLE",
    "TAKEOFF",
    "HOLD",
    "STREAM",
    "LAND",
    "RTL",
    "RTL_LAND",
)
_FLIGHT_MODES = {
    IDLE: FlightMode.GUIDED,
    TAKEOFF: FlightMode.GUIDED,
    HOLD: FlightMode.GUIDED,
    STREAM: FlightMode.GUIDED,
    LAND: FlightMode.LANDING,
    RTL_GO: FlightMode.RTL,
    RTL_LAND: FlightMode.RTL,
}
_MODE_NAMES = {
    IDLE: "IDLE",
    TAKEOFF: "TAKEOFF",
    HOLD: "HL_HOLD",
    STREAM: "VELOCITY",
    LAND: "LAND",
    RTL_GO: "RTL",
    RTL_LAND: "RTL_LAND",
}


def _init_drivers() -> None:
    """cflib's drivers, once per process (``init_drivers`` appends to a global list each call).

    ``memory://`` (`memory.MemoryDriver`, a peer in this process) comes last, after cflib's own.
    """
    global _drivers_ready
    import cflib.crtp

    from antalate_lcm.autopilot.crazyflie import memory

    with _drivers_lock:
        if not _drivers_ready:
            cflib.crtp.init_drivers()
            _drivers_ready = True
    memory.install()


class CrazyflieAutopilot(VehicleAdapter[Params, Any]):
    """A Crazyflie through cflib; see the module docstring for the rules on top of cflib."""

    name = "crazyflie"
    blocking = True  # arm and takeoff wait for the supervisor's confirmation over the radio
    params_model: ClassVar[type[BaseModel]] = Params

    def _setup(self) -> None:
        """The constructor's ``link=`` makes the cflib ``Crazyflie`` for each connection (default: cflib's
        own, its drivers installed, `_default_link`)."""
        p = self._p
        self.frame = LocalFrame(p.origin_lat, p.origin_lon, p.origin_heading)
        self.last_refusal = ""
        self._lock = threading.RLock()
        self._cf: Any = None
        self._reading = Reading()
        self._heard = LinkAge(self.clock)  # any packet: log data, or the answers to cflib's latency pings
        self._connected = False
        self._no_kalman = False
        self._link_error = ""
        self._mode = IDLE
        self._mode_at = -math.inf
        self._failsafe = ""
        self._velocity: tuple[float, float, float, float, Frame, float] | None = None
        self._height = 0.0
        self._takeoff_alt = 0.0
        #: RTL's target: the take-off point, else where the vehicle was first seen on the ground, else
        #: (an HLC restarted in the air) the frame's origin.
        self._home: tuple[float, float] | None = None
        self._rtl_deadline = math.inf
        #: on the ground and not armed by us: report disarmed whatever auto-arming says (a CF2.x arms
        #: itself at power-on), and refuse a take-off that arm() did not precede
        self._ground_idle = True
        #: the high-level command that set the mode, until the firmware answers it: (command byte,
        #: when sent, how to send it again); resent by the control loop (see the module docstring)
        self._hl_pending: tuple[int, float, str] | None = None
        self._hl_refused: tuple[int, int] | None = None  # (command byte, result) of the last refusal
        self._takeoff_accepted = False  # the firmware answered the last take-off 0 (its planner took it)
        self._critical_since = math.inf
        self._blind_land_at = -math.inf
        self._blind_landing = False  # landings sent into a lost link: resent once it answers again
        self._last_tick = -math.inf
        self._reconnecting = False
        self._reconnect_at = -math.inf
        self.reconnects = 0

    # ------------------------------------------------------------------ link
    def connect(self) -> None:
        try:
            import cflib  # noqa: F401
        except ImportError:
            raise AutopilotError(CFLIB_MISSING) from None
        self._open_link()
        if not self._workers.running:
            self._workers.start((self._control_loop, f"crazyflie-{self._p.uri}"))

    def _default_link(self, params: Params) -> Any:
        """cflib's ``Crazyflie`` (its drivers, ``memory://`` included, installed once per process)."""
        from cflib.crazyflie import Crazyflie

        _init_drivers()
        return Crazyflie(rw_cache=params.cache_dir or None)

    def _open_link(self) -> None:
        from cflib.crazyflie.log import LogConfig

        p = self._p
        cf = self._opener(p)
        ready = threading.Event()
        failure: list[str] = []

        def failed(uri: str, message: str) -> None:
            failure.append(str(message).splitlines()[0] if message else "connection failed")
            ready.set()

        cf.fully_connected.add_callback(lambda uri: ready.set())
        cf.connection_failed.add_callback(failed)
        cf.connection_lost.add_callback(self._on_connection_lost)
        cf.packet_received.add_callback(self._on_packet)
        cf.add_port_callback(_HL_PORT, self._on_hl_answer)
        cf.open_link(p.uri)
        if not ready.wait(p.connect_timeout) or failure:
            why = failure[0] if failure else f"no answer within {p.connect_timeout:g} s"
            self._close_quietly(cf)
            raise AutopilotError(f"cannot connect to the Crazyflie at {p.uri}: {why}")
        no_kalman = False
        try:
            for block, names in LOG_BLOCKS.items():
                config = LogConfig(name=block, period_in_ms=p.log_period_ms)
                for var in names:
                    config.add_variable(var)
                try:
                    cf.log.add_config(config)
                except KeyError as exc:
                    if block == "antalate_estimator":
                        no_kalman = True  # arm() refuses and says why
                        continue
                    raise AutopilotError(
                        f"the Crazyflie at {p.uri} lacks a log variable the adapter needs: "
                        f"{exc.args[0] if exc.args else exc}"
                    ) from None
                config.data_received_cb.add_callback(self._on_log)
                config.start()
        except AutopilotError:
            self._close_quietly(cf)
            raise
        with self._lock:
            self._cf = cf
            self._no_kalman = no_kalman
            self._link_error = ""
        deadline = self.clock() + p.connect_timeout
        while self.clock() < deadline:
            with self._lock:
                if self._reading.has_pose:
                    self._connected = True
                    log.info("connected to the Crazyflie at %s", p.uri)
                    return
            time.sleep(0.02)
        with self._lock:
            self._cf = None
        self._close_quietly(cf)
        raise AutopilotError(
            f"the Crazyflie at {p.uri} sent no state (log blocks) within {p.connect_timeout:g} s"
        )

    @staticmethod
    def _close_quietly(cf: Any) -> None:
        """Close a cflib link *without* cflib's parting zero-thrust set-point.

        ``Crazyflie.close_link`` sends ``send_setpoint(0, 0, 0, 0)`` first, which stops the motors of a
        flying Crazyflie: a reconnection attempt that timed out just as the radio came back would drop
        the vehicle. The driver is closed first, so close_link finds no link to send on. Before it, the
        10 Hz latency pings are stopped: a ping already past cflib's link check would be sent on the
        closed socket, and the link error it raises makes cflib join the ping thread from itself.
        """
        try:
            cf.link_statistics.stop()
            link, cf.link = cf.link, None
            if link is not None:
                link.close()
            cf.close_link()
        except Exception:  # noqa: BLE001 - closing a half-open link must not mask the real error
            log.debug("closing a cflib link raised", exc_info=True)

    def close(self) -> None:
        self._workers.halt()
        with self._lock:
            cf, self._cf = self._cf, None
            flying = self._reading.flags.flying
            self._connected = False
        if cf is None:
            return
        if flying:
            log.warning(
                "shutting down with the Crazyflie at %s in the air: emergency stop (motors off)", self._p.uri
            )
            for _ in range(3):  # a radio may drop one; the stop is idempotent
                cf.supervisor.send_emergency_stop()
        self._close_quietly(cf)

    def _on_packet(self, _pk: Any) -> None:
        self._heard.heard()

    def _on_hl_answer(self, pk: Any) -> None:
        """crtp_commander_high_level.c answers each command: byte 0 the command, byte 3 the result."""
        data = bytes(pk.data)
        if len(data) < 4:
            return
        cmd, result = data[0], data[3]
        with self._lock:
            pending = self._hl_pending
            if pending is not None and pending[0] == cmd:
                self._hl_pending = None
            if result != 0:
                self._hl_refused = (cmd, result)
            elif cmd == _HL_TAKEOFF:
                self._takeoff_accepted = True

    def _on_log(self, _timestamp: int, data: dict[str, Any], _config: Any) -> None:
        with self._lock:
            self._reading = r = apply_log(self._reading, data)
            if self._home is None and r.has_pose and "supervisor.info" in data and not r.flags.flying:
                self._home = (r.x, r.y)

    def _on_connection_lost(self, uri: str, message: str) -> None:
        with self._lock:
            self._link_error = str(message).splitlines()[0] if message else "link lost"
            self._connected = False
        log.warning(
            "cflib lost the link to %s: %s; reopening it every %g s", uri, self._link_error, _RECONNECT_S
        )

    def _reconnect(self) -> None:
        """Reopen a link cflib closed (on the reconnect thread); the old Crazyflie object is dropped."""
        with self._lock:
            old, self._cf = self._cf, None
        if old is not None:
            self._close_quietly(old)
        try:
            self._open_link()
        except AutopilotError as exc:
            log.info("reopening the link failed: %s", exc)
        else:
            self.reconnects += 1
            log.warning("link to the Crazyflie at %s reopened", self._p.uri)
            if self._stop.is_set():  # closed meanwhile: do not leave this link open
                with self._lock:
                    cf, self._cf, self._connected = self._cf, None, False
                if cf is not None:
                    self._close_quietly(cf)
        finally:
            with self._lock:
                self._reconnecting = False

    # ------------------------------------------------------------------ commands
    def _require_link(self) -> Any:
        with self._lock:
            cf = self._cf
            if cf is None or not self._connected:
                raise AutopilotError(
                    f"not connected to the Crazyflie at {self._p.uri}"
                    + (f" ({self._link_error})" if self._link_error else "")
                )
            return cf

    def _refuse(self, reason: str) -> bool:
        self.last_refusal = reason
        log.warning("arming refused: %s", reason)
        return False

    def arm(self) -> bool:
        cf = self._require_link()
        self.last_refusal = ""
        with self._lock:
            reading = self._reading
            age = self._heard()
            no_kalman = self._no_kalman
        if age > self._p.link_stale_after:
            return self._refuse(f"the link is {age:.1f} s old")
        blocker = reading.flags.arm_blocker()
        if blocker:
            return self._refuse(blocker)
        if no_kalman:
            return self._refuse(
                "kalman.varPX/PY/PZ are not in the log TOC: the pre-flight estimator check needs "
                "the Kalman estimator (stabilizer.estimator = 2)"
            )
        problem = estimator_problem(reading, self._p.max_position_variance)
        if problem:
            return self._refuse(problem)
        warning = battery_warning(reading.pm_state)
        if warning:
            return self._refuse(f"battery low: {warning}, {reading.vbat:.2f} V")
        if reading.vbat <= self._p.low_voltage:
            return self._refuse(
                f"battery low: {reading.vbat:.2f} V <= low_voltage {self._p.low_voltage:g} V "
                "(the firmware reports lowPower 5 s after it)"
            )
        with self._lock:
            self._ground_idle = False
        cf.supervisor.send_arming_request(True)
        deadline = self.clock() + self._p.arm_timeout
        while self.clock() < deadline:
            if self._reading.flags.armed:
                return True
            time.sleep(0.02)
        flags = self._reading.flags
        return self._refuse(
            f"the supervisor did not arm within {self._p.arm_timeout:g} s"
            + (
                f": {flags.arm_blocker()}"
                if flags.arm_blocker()
                else f" (supervisor.info 0x{self._reading.info:04x})"
            )
        )

    def disarm(self) -> None:
        cf = self._require_link()
        cf.supervisor.send_arming_request(False)
        with self._lock:
            self._ground_idle = True

    def takeoff(self, alt: float) -> None:
        check_takeoff_altitude(alt)
        cf = self._require_link()
        with self._lock:
            r = self._reading
            if not r.flags.armed or self._ground_idle:
                raise AutopilotError("not armed")
            if r.flags.flying and self._mode != IDLE:
                # planner.c plan_takeoff answers 1 unless its planner is idle; worse, mid-stream the
                # stream has stopped the planner, which would take it while the stream's priority
                # stays up and the stream ends: the watchdog's cut 2 s later
                raise AutopilotError(
                    f"takeoff refused: the Crazyflie is flying ({_MODE_NAMES[self._mode]}); "
                    "its planner takes off only when idle: land first"
                )
            self._leave_stream(cf)
            self._hl_pending = None
            mode0, home0 = self._mode, self._home
            self._home = (r.x, r.y)
            self._set_mode(TAKEOFF)
            self._takeoff_alt = alt
            self._failsafe = ""
            self._hl_refused = None
            self._takeoff_accepted = False
            z0 = r.z
            was_flying = r.flags.flying
        cf.high_level_commander.takeoff(alt, takeoff_duration(z0, alt, self._p.climb_speed), yaw=None)
        deadline = self.clock() + self._p.takeoff_confirm
        while self.clock() < deadline:
            r = self._reading
            refused = self._hl_refused if self._hl_refused and self._hl_refused[0] == _HL_TAKEOFF else None
            # Lifting, or flying by the firmware's word -- but a flying bit already set when the
            # command went (a hover, a landing still running) is no take-off: the planner refuses
            # one unless idle (planner.c plan_takeoff) and only its answer says which.
            flying = r.flags.flying and (not was_flying or self._takeoff_accepted)
            if refused is None and (flying or r.z > z0 + 0.05):
                return
            if refused is not None:
                with self._lock:  # what it was doing goes on (a hover, a landing)
                    self._set_mode(mode0 if was_flying else IDLE)
                    self._home = home0 if was_flying else self._home
                raise AutopilotError(
                    "the Crazyflie refused the take-off: "
                    + (
                        "its supervisor cannot fly (EBUSY: not armed, locked or crashed)"
                        if refused[1] == 16
                        else f"its planner is busy with a trajectory or a landing (result {refused[1]})"
                    )
                )
            time.sleep(0.02)
        with self._lock:
            self._set_mode(mode0 if was_flying else IDLE)
        blocker = self._reading.flags.arm_blocker()
        raise AutopilotError(
            f"the Crazyflie did not take off within {self._p.takeoff_confirm:g} s: "
            + (blocker or "the supervisor never reported flying")
        )

    def land(self) -> None:
        cf = self._require_link()
        with self._lock:
            self._start_landing(cf, LAND)

    def rtl(self) -> None:
        cf = self._require_link()
        with self._lock:
            r = self._reading
            self._leave_stream(cf)
            if self._home is None:
                log.warning(
                    "RTL with no take-off point known (connected in the air): returning to the origin"
                )
                self._home = (0.0, 0.0)
            hx, hy = self._home
            distance = math.hypot(r.x - hx, r.y - hy)
            if distance <= self._p.rtl_tolerance:
                self._start_landing(cf, RTL_LAND)
                return
            duration = goto_duration(distance, self._p.rtl_speed)
            self._set_mode(RTL_GO)
            self._rtl_deadline = self.clock() + duration + 5.0
            self._switch(cf, "rtl")
        log.info("RTL: go_to the take-off point (%.2f, %.2f), %.1f m in %.1f s", hx, hy, distance, duration)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        check_velocity(vx, vy, vz, yaw_rate)
        cf = self._require_link()
        with self._lock:
            if self._mode in (LAND, RTL_GO, RTL_LAND):
                return  # a hover (or a late set-point) never cancels a landing or the way home
            if is_zero(vx, vy, vz, yaw_rate):
                self._velocity = None
                if self._mode == STREAM:
                    self._hold(cf)
                return
            if not self._reading.flags.flying:
                raise AutopilotError("not flying: velocity set-points are for the air")
            if self._mode != STREAM:
                # the HLC steers from 95 % of the take-off altitude: a body-frame height target
                # started during the climb still ends at the altitude asked for
                z = self._reading.z
                self._height = max(z, self._takeoff_alt) if self._mode == TAKEOFF else z
                self._set_mode(STREAM)
                self._hl_pending = None  # the stream supersedes a hold or a landing not yet answered
            self._velocity = (vx, vy, vz, yaw_rate, Frame(frame), self.clock())
            self._send_setpoint(
                cf, build_setpoint(vx, vy, vz, yaw_rate, Frame(frame), self.frame, self._height)
            )

    # ------------------------------------------------------------------ internals (under self._lock)
    def _set_mode(self, mode: str) -> None:
        self._mode = mode
        self._mode_at = self.clock()

    def _leave_stream(self, cf: Any) -> None:
        """Before a high-level command: a velocity stream ends (the command's `_switch` notifies)."""
        self._velocity = None

    def _switch(self, cf: Any | None, what: str) -> None:
        """Send the high-level command `what` as *command, notify, command* and await its answer.

        Never the notification alone (the module docstring says why). `cf` None (cflib closed the
        link) only records the command: the control loop sends it once the link is open again.
        """
        cmd = {"hold": _HL_GOTO, "rtl": _HL_GOTO, "land": _HL_LAND}[what]
        self._hl_pending = (cmd, self.clock(), what)
        if cf is None:
            return
        self._send_hl(cf, what)
        cf.commander.send_notify_setpoint_stop()
        self._send_hl(cf, what)

    def _send_hl(self, cf: Any, what: str) -> None:
        r = self._reading
        if what == "hold":
            cf.high_level_commander.go_to(0.0, 0.0, 0.0, 0.0, 0.5, relative=True)
        elif what == "land":
            z = r.z if math.isfinite(r.z) else 1.0
            cf.high_level_commander.land(0.0, max(z / self._p.land_speed, 1.0), yaw=None)
        else:  # rtl: the take-off point at the current height, at rtl_speed from where it is now
            hx, hy = self._home or (0.0, 0.0)
            duration = goto_duration(math.hypot(r.x - hx, r.y - hy), self._p.rtl_speed)
            cf.high_level_commander.go_to(hx, hy, r.z, math.radians(r.yaw), duration)

    def _hold(self, cf: Any | None) -> None:
        """Back to the high-level commander, holding the current position."""
        self._leave_stream(cf)
        self._set_mode(HOLD)
        self._switch(cf, "hold")

    def _start_landing(self, cf: Any | None, mode: str) -> None:
        self._leave_stream(cf)
        self._set_mode(mode)
        self._switch(cf, "land")

    def _send_setpoint(self, cf: Any, sp: SetPoint) -> None:
        if sp.kind == "world":
            cf.commander.send_velocity_world_setpoint(*sp.values)
        else:
            cf.commander.send_hover_setpoint(*sp.values)

    def _control_loop(self) -> None:
        period = 1.0 / self._p.control_hz
        while not self._stop.wait(period):
            try:
                self._tick()
            except Exception:  # noqa: BLE001 - the control thread must outlive one bad tick
                log.exception("crazyflie control tick failed")

    def _tick(self) -> None:
        now = self.clock()
        p = self._p
        with self._lock:
            if (
                self._link_error
                and not self._connected
                and not self._reconnecting
                and not self._stop.is_set()
                and now - self._reconnect_at >= _RECONNECT_S
            ):
                self._reconnecting = True
                self._reconnect_at = now
                threading.Thread(target=self._reconnect, name="crazyflie-reconnect", daemon=True).start()
            # cflib closed the link: no cf to send on, but the timers below still run and what they
            # decide (a hold, a landing) is sent once the link is open again
            cf = self._cf if self._connected else None
            if cf is None and not self._link_error:
                return  # closing, or never opened
            dt, self._last_tick = now - self._last_tick, now
            age = self._heard()
            r = self._reading
            flying = r.flags.flying
            if self._mode == STREAM:
                if cf is None or age > p.link_stale_after:
                    log.warning("link %.1f s old: the high-level commander holds the Crazyflie", age)
                    self._hold(cf)
                elif self._velocity is None or now - self._velocity[5] > p.velocity_hold:
                    self._hold(cf)
                else:
                    vx, vy, vz, rate, frame, _ = self._velocity
                    if frame is Frame.BODY:
                        self._height = next_height(self._height, vz, dt)
                    self._send_setpoint(cf, build_setpoint(vx, vy, vz, rate, frame, self.frame, self._height))
            self._check_battery(cf, now, flying)
            lost = p.link_loss_land > 0 and age > p.link_loss_land
            if lost and flying and self._mode != IDLE and now - self._blind_land_at >= 1.0:
                if self._mode != LAND:
                    log.warning("link lost for %.1f s in the air: landing blindly", age)
                if not self._failsafe:
                    self._failsafe = (
                        f"link lost for more than {p.link_loss_land:g} s: the adapter commanded a landing"
                    )
                self._blind_land_at = now
                self._blind_landing = True
                self._start_landing(cf, LAND)
            elif self._blind_landing and cf is not None and age < p.link_stale_after:
                self._blind_landing = False
                if self._mode == LAND and flying:
                    log.warning("link back: the landing sent while it was lost is sent again")
                    self._start_landing(cf, LAND)
            pending = self._hl_pending
            if pending is not None and cf is not None and now - pending[1] >= _HL_RESEND_S:
                if flying:
                    log.info("no answer to the high-level %s: sent again", pending[2])
                    self._switch(cf, pending[2])
                else:
                    self._hl_pending = None
            if self._mode == RTL_GO:
                hx, hy = self._home or (0.0, 0.0)
                arrived = math.hypot(r.x - hx, r.y - hy) <= p.rtl_tolerance and math.hypot(r.vx, r.vy) < 0.05
                if arrived or now > self._rtl_deadline:
                    self._start_landing(cf, RTL_LAND)
            if (
                cf is not None
                and self._mode in (LAND, RTL_LAND)
                and not flying
                and now - self._mode_at > 0.5
                and age < p.link_stale_after
            ):
                cf.supervisor.send_arming_request(False)
                self._ground_idle = True
                self._hl_pending = None
                self._set_mode(IDLE)
                self._failsafe = ""

    def _check_battery(self, cf: Any | None, now: float, flying: bool) -> None:
        """Land where it is once ``pm.vbat`` has stayed below ``critical_voltage`` in the air."""
        p = self._p
        vbat = self._reading.vbat
        if not (math.isfinite(vbat) and vbat < p.critical_voltage):
            self._critical_since = math.inf
            return
        if math.isinf(self._critical_since):
            self._critical_since = now
        if not flying or self._mode in (IDLE, LAND) or now - self._critical_since < p.critical_land_after:
            return
        log.warning("battery critical in the air (%.2f V): landing where it is", vbat)
        self._failsafe = (
            f"battery critical: {vbat:.2f} V < {p.critical_voltage:g} V (a Crazyflie built with "
            "CONFIG_PM_AUTO_SHUTDOWN powers off 5 s later): the adapter commanded a landing"
        )
        self._start_landing(cf, LAND)

    # ------------------------------------------------------------------ state
    def state(self) -> AutopilotState:
        with self._lock:
            r = self._reading
            connected = self._connected and self._cf is not None
            age = self._heard()
            mode = self._mode
            failsafe = self._failsafe
            ground_idle = self._ground_idle
        flags = r.flags
        common: dict[str, Any] = {
            "connected": connected,
            "link_age": age,
            "battery": float(r.battery_level) if r.battery_level >= 0 else -1.0,
            "voltage": r.vbat,
            "cells": self._p.cells,
            "battery_warning": battery_warning(r.pm_state),
            "armed": flags.armed and not (ground_idle and not flags.flying),
            "in_air": flags.flying,
            "mode": "LOCKED" if flags.locked else _MODE_NAMES[mode],
            "flight_mode": _FLIGHT_MODES[mode],
            "failsafe": failsafe if mode == LAND else "",
        }
        if not r.has_pose:
            return AutopilotState(**common)
        lat, lon = self.frame.to_wgs84(r.x, r.y)
        vn, ve, vd = self.frame.velocity_ned(r.vx, r.vy, r.vz)
        return AutopilotState(
            lat=lat, lon=lon, alt=r.z, heading=self.frame.heading(r.yaw), vn=vn, ve=ve, vd=vd, **common
        )
