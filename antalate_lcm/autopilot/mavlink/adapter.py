"""`MavlinkAutopilot`: ArduCopter over MAVLink -- SITL or a real flight controller (docs/design.md §7, ``mavlink``).

The adapter is a small ground station: it speaks pymavlink over serial, UDP or TCP, keeps its own
picture of the vehicle from the telemetry the autopilot streams, and turns the HLC's few verbs into
ArduCopter's dialect (GUIDED mode, arming, MAV_CMD_NAV_TAKEOFF, velocity targets, LAND and RTL modes).

ArduCopter facts it is built around
-----------------------------------
* **A mode set while the autopilot is still booting is acknowledged, then silently reverted** when
  initialisation ends. So `arm` first waits for HEARTBEAT ``system_status`` STANDBY, and every mode
  change is confirmed by a HEARTBEAT received *after* the COMMAND_ACK showing the new ``custom_mode``.
* **Arming can succeed before the EKF uses GPS**; GUIDED then misbehaves. `arm` waits (up to
  ``ready_timeout``) for EKF_STATUS_REPORT with an absolute horizontal position (and not in constant
  position mode) and a GPS_RAW_INT 3D fix before it touches the mode or the motors.
* **MAV_CMD_NAV_TAKEOFF is refused outside GUIDED**, and an armed copter that does not take off disarms
  itself after ~10 s (DISARM_DELAY): the HLC takes off right after a successful arm, so that is enough.
* **Velocity targets expire after GUID_TIMEOUT (3 s)** in GUIDED. A background thread resends the current
  set-point ``velocity_resend_hz`` times a second while the copter flies in GUIDED -- but **never one
  older than ``setpoint_timeout``** (counted from the HLC's `set_velocity` call) and **never while the
  link is stale** (no message from the vehicle for ``link_stale_after``): a TCP link or a buffering radio
  keeps what is written during a cut and delivers it all when the link returns, and a field trial flew
  6.1 m on such a backlog while the HLC said LLC_DOWN. When messages flow again after a stale spell,
  a zero set-point goes out at once, so it reaches the vehicle right behind any backlog and stops it.
* A zero set-point while EXTENDED_SYS_STATE says TAKEOFF is not sent: the HLC's "hover once
  airborne" would otherwise cut the takeoff climb short a little below its target.
* **A mode change is a pilot's or a failsafe's**: ArduCopter's fence, battery, EKF and GCS failsafes
  switch modes exactly like a pilot's switch. `failsafe.FailsafeTracker` attributes a mode change the
  adapter did not command to the failsafe ArduPilot reported around it (SYS_STATUS health, FENCE_STATUS,
  BATTERY_STATUS, STATUSTEXT): `AutopilotState.failsafe` names it and RTL/LAND/BRAKE stay computer
  control (BRAKE = `FlightMode.HOLD`). Without such evidence LAND and the RTL family are still computer
  control; every other mode is a pilot's (``FlightMode.MANUAL``) and the HLC leaves the vehicle alone.
* **Link loss is HEARTBEAT silence**: `AutopilotState.link_age` is the age of the autopilot's last
  HEARTBEAT on the adapter's clock; the HLC compares it with ``link_timeout``.
* Every COMMAND_LONG is matched to its COMMAND_ACK by command id (only one command is in flight at a
  time); a command without ACK is sent once more (``confirmation`` 1) before `AutopilotError`.

Vehicle pre-flight checks
-------------------------
On connect the adapter reads the vehicle's own failsafe parameters (`vehicle_checks`: FS_GCS_ENABLE,
SYSID_MYGCS, GUID_TIMEOUT, FENCE_*, BATT_*) with PARAM_REQUEST_READ. Each one that leaves the vehicle
unprotected is written (PARAM_SET, confirmed by PARAM_VALUE) when ``configure_vehicle`` is set, and
otherwise logged as a warning with the exact value to set; with ``require_vehicle_failsafes`` `arm`
returns False and `last_refusal` names the parameter (the HLC puts it into its ``hlc_error_t``).

Identity and signing
--------------------
The adapter sends a GCS HEARTBEAT (``heartbeat_hz``) as system ``source_system`` (default **245**),
component ``source_component`` (default 191, MAV_COMP_ID_ONBOARD_COMPUTER). 245 rather than the
ground-station-typical 255 so that the adapter and a ground station (Mission Planner, QGroundControl,
MAVProxy: all 255) can share a link without mixing up their acknowledgements. ArduCopter's GCS failsafe
only watches heartbeats from ``SYSID_MYGCS`` (default 255): the pre-flight check says so.
With ``signing_key`` every message is MAVLink 2 signed and unsigned or badly signed messages from the
link are dropped and counted (`signing_rejected`).

The vehicle is found by its first HEARTBEAT from an autopilot component (MAV_COMP_ID_AUTOPILOT1, not a
GCS or a gimbal) unless ``target_system``/``target_component`` pin it; messages from anyone else are
ignored.

Threads
-------
``connect()`` opens the link (`link.MavLink`: pymavlink's connection, or a `link.MemoryLink` given
as ``link=``) and starts a receive thread (decodes everything, keeps the `vehicle.Vehicle` picture under
a lock, wakes the command waiters) and a transmit thread (our HEARTBEAT, the velocity resend, and the
telemetry re-request after a reboot or a reopened link: no thread is started for it).
Commands are blocking (`blocking` = True: the HLC runs them on its worker thread); `set_velocity` and
`state` never wait. A TCP or serial link that drops is reopened by the receive thread every second
until `close`. The rules themselves are pure: `dialect` (modes, names, messages), `vehicle` (telemetry
into the picture, ACK matching), `setpoints` (when a velocity target may go out) and `streams` (the
telemetry requests).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
from collections.abc import Callable
from typing import Any, ClassVar

from pydantic import BaseModel
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.autopilot.base import (
    AutopilotError,
    AutopilotState,
    Frame,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.autopilot.kit import VehicleAdapter, Workers
from antalate_lcm.autopilot.mavlink import dialect, vehicle_checks
from antalate_lcm.autopilot.mavlink.dialect import (
    COPTER_MODES,
    SET_MODE_ACK,
    VELOCITY_TYPE_MASK,
    cmd_name,
    mode_name,
    result_name,
)
from antalate_lcm.autopilot.mavlink.failsafe import FLIGHT_MODES
from antalate_lcm.autopilot.mavlink.link import MavLink, PymavlinkLink
from antalate_lcm.autopilot.mavlink.params import DEFAULTS, Params
from antalate_lcm.autopilot.mavlink.setpoints import Setpoint, SetpointRules, Verdict
from antalate_lcm.autopilot.mavlink.signing import signing_key
from antalate_lcm.autopilot.mavlink.streams import StreamRequest
from antalate_lcm.autopilot.mavlink.vehicle import Vehicle
from antalate_lcm.autopilot.mavlink.vehicle_checks import Finding
from antalate_lcm.base.ratelimit import RateLimitedLog

log = logging.getLogger("antalate.autopilot.mavlink")

__all__ = [
    "COPTER_MODES",
    "DEFAULTS",
    "FLIGHT_MODES",
    "LinkOpener",
    "MavlinkAutopilot",
    "Params",
    "VELOCITY_TYPE_MASK",
    "mode_name",
]

#: Opens the link for the validated parameters; called on `connect` and on every reopen.
LinkOpener = Callable[[Params], MavLink]

_REOPEN_DELAY = 1.0  # s between attempts to reopen a dropped TCP/serial link
_RX_POLL = 0.1  # s the receive thread blocks at most, so close() is prompt
_SETTLE = 3.0  # s connect() waits at most for the first position and landed-state reports


class MavlinkAutopilot(VehicleAdapter[Params, MavLink]):
    """ArduCopter through pymavlink; see the module docstring for what it waits for and why.

    ``link`` opens the link instead of pymavlink's connection (a `link.MemoryLink` in tests).
    """

    name = "mavlink"
    blocking = True
    params_model: ClassVar[type[BaseModel]] = Params

    def _setup(self) -> None:
        p = self._p
        self.connection: str = p.connection
        self.source_system = p.source_system
        self._ack_timeout = p.ack_timeout
        self._mode_timeout = p.mode_timeout
        self._rules = SetpointRules(
            resend_period=1.0 / p.velocity_resend_hz if p.velocity_resend_hz > 0 else 0.0,
            timeout=p.setpoint_timeout,
            stale_after=p.link_stale_after,
        )
        self._heartbeat_period = 1.0 / p.heartbeat_hz
        self._signed = bool(p.signing_key.strip())
        if self._signed:
            signing_key(p.signing_key)  # a bad key fails here, at configuration time

        self._link: MavLink | None = None
        self._cond = threading.Condition()  # guards _v, _setpoint, _target; notified on every message
        self._send_lock = threading.Lock()  # guards _link replacement against a send
        self._cmd_lock = threading.Lock()  # one command (and its ACK wait) at a time
        self._v = self._new_vehicle()
        self._setpoint: Setpoint | None = None
        self._streams: StreamRequest | None = None  # a telemetry re-request the transmit thread runs
        self._target: tuple[int, int] | None = None  # (system, component) of the autopilot
        self._connected = False
        self._closed = False
        self._warned_autopilot = False
        self._rate_log = RateLimitedLog(log, period=10.0, clock=self.clock)
        #: The last arming refusal's reason (STATUSTEXT, or the failed pre-flight check), for the HLC.
        self.last_refusal = ""
        #: What the last vehicle pre-flight check found (empty: the vehicle's failsafes protect it).
        self.vehicle_findings: list[Finding] = []
        #: Messages dropped for a missing or wrong MAVLink 2 signature (with ``signing_key``).
        self.signing_rejected = 0
        #: Set-points not sent because they were too old or the link was stale.
        self.setpoints_withheld = 0
        self._vehicle_ok = False  # the last pre-flight check found nothing

    def _default_link(self, params: Params) -> MavLink:
        """The real link: ``connection`` through pymavlink (serial, UDP, TCP), signed with ``signing_key``."""
        return PymavlinkLink(
            params.connection,
            source_system=params.source_system,
            source_component=params.source_component,
            baud=params.baud,
            signing_key=signing_key(params.signing_key) if params.signing_key.strip() else None,
        )

    #: The picture of the vehicle its telemetry is read into (a flight stack's own subclass).
    _vehicle_class: ClassVar[type[Vehicle]] = Vehicle
    #: The flight stack the adapter speaks: its MAV_AUTOPILOT, and its name for the warning.
    _autopilot_kind: ClassVar[tuple[int, str]] = (mav.MAV_AUTOPILOT_ARDUPILOTMEGA, "ArduPilot")

    def _new_vehicle(self) -> Vehicle:
        # A HEARTBEAT showing the mode we commanded counts as ours for the longest a mode change can take.
        window = 2 * self._ack_timeout + self._mode_timeout + 1.0
        return self._vehicle_class(source_system=self.source_system, command_window=window)

    # ----------------------------------------------------------------- Autopilot contract

    def connect(self) -> None:
        """Open the link, find the autopilot by its HEARTBEAT, ask for telemetry.

        Bounded by ``connect_timeout``; on failure everything is released again, so the HLC's retry
        starts from scratch.
        """
        if self._connected:
            return
        self._closed = False
        self._workers = Workers()  # a fresh stop event: a thread of the last connection stays stopped
        timeout = self._p.connect_timeout
        deadline = self.clock() + timeout
        try:
            self._link = self._open_until(deadline)
            self._start_threads()
            if not self._wait(lambda v: v.heartbeats > 0, deadline - self.clock()):
                rejected = (
                    (
                        f"; {self.signing_rejected} message(s) dropped for a missing or wrong MAVLink 2 "
                        "signature: does the vehicle have the same signing key?"
                    )
                    if self.signing_rejected
                    else ""
                )
                raise AutopilotError(
                    f"no HEARTBEAT from {self.connection} within {timeout:g} s: "
                    f"is SITL/the autopilot running, and is this the right port?{rejected}"
                )
            self._request_streams()
            self._wait(lambda v: v.position_seen and v.landed_state is not None, _SETTLE)
        except BaseException:
            self._shutdown()
            raise
        with self._cond:
            target = self._target
            summary = self._v.summary()
            self._connected = True
        log.info(
            "connected to autopilot %s over %s: %s%s",
            target,
            self.connection,
            summary,
            ", MAVLink 2 signed" if self._signed else "",
        )
        if self._p.check_vehicle:
            try:
                with self._cmd_lock:
                    self._check_vehicle()
            except AutopilotError as exc:  # the check must never cost the connection
                log.warning("vehicle pre-flight check failed: %s", exc)

    def close(self) -> None:
        self._closed = True
        self._connected = False
        self._shutdown()

    #: The mode the adapter arms in (and flies its commands from).
    _arm_mode: ClassVar[str] = "GUIDED"

    def arm(self) -> bool:
        """Wait until the vehicle can fly, switch to `_arm_mode`, arm; False if the autopilot refused."""
        with self._cmd_lock:
            self._require_link("arm")
            with self._cond:
                ready = self._v.armed and self._armed_ours()
            if ready:
                return True
            if self._p.require_vehicle_failsafes:
                findings = [] if self._vehicle_ok else self._check_vehicle()
                if findings:
                    self.last_refusal = "vehicle pre-flight check: " + "; ".join(f.text() for f in findings)
                    log.warning("arming refused: %s", self.last_refusal)
                    return False
            self._wait_ready()
            self._enter_arm_mode()
            with self._cond:
                mark = self._v.messages
            result = self._command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            if result != mav.MAV_RESULT_ACCEPTED:
                with self._cond:
                    reason = self._v.texts_since(mark) or self._v.latest_prearm()
                self.last_refusal = reason
                log.warning("arming refused (%s)%s", result_name(result), f": {reason}" if reason else "")
                return False
            if not self._wait(lambda v: v.armed, self._mode_timeout):  # disarmed before: a fresh HEARTBEAT
                raise AutopilotError(
                    f"arming acknowledged but no HEARTBEAT showed the motors armed "
                    f"within {self._mode_timeout:g} s"
                )
            with self._cond:
                mode = self._v.mode
                self._armed_in(mode)
            if mode != self._arm_mode:
                raise AutopilotError(
                    f"armed, but the mode is {mode}, not {self._arm_mode} (changed behind our back)"
                )
            log.info("armed in %s", self._arm_mode)
            return True

    def _armed_ours(self) -> bool:
        """Whether an armed vehicle is already ours to command (lock held): arming again is then a no-op."""
        return self._v.mode == self._arm_mode

    def _enter_arm_mode(self) -> None:
        self._set_mode(self._arm_mode)

    def _armed_in(self, mode: str) -> None:
        """The vehicle armed showing `mode` (lock held)."""

    def disarm(self) -> None:
        with self._cmd_lock:
            self._require_link("disarm")
            with self._cond:
                mark = self._v.messages
            result = self._command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)
            if result != mav.MAV_RESULT_ACCEPTED:
                raise AutopilotError(f"disarm refused ({result_name(result)}){self._because(mark)}")

    def takeoff(self, alt: float) -> None:
        check_takeoff_altitude(alt)
        with self._cmd_lock:
            self._require_link("takeoff")
            self._clear_setpoint()
            with self._cond:
                mark, mode, armed = self._v.messages, self._v.mode, self._v.armed
            result = self._command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, float(alt))
            self._check_takeoff_accepted(result, alt, mode, armed, mark)
            log.info("taking off to %g m", alt)

    def _check_takeoff_accepted(self, result: int, alt: float, mode: str, armed: bool, mark: int) -> None:
        """`AutopilotError` saying why, unless MAV_CMD_NAV_TAKEOFF was accepted (`mode` and `armed` as sent)."""
        if result != mav.MAV_RESULT_ACCEPTED:
            state = f"mode {mode}, {'armed' if armed else 'disarmed'}"
            raise AutopilotError(
                f"takeoff to {alt:g} m refused ({result_name(result)}; {state}){self._because(mark)}"
            )

    #: The flight stack's modes for `land` and `rtl`.
    _land_mode: ClassVar[str] = "LAND"
    _rtl_mode: ClassVar[str] = "RTL"

    def land(self) -> None:
        self._mode_command("land", self._land_mode)

    def rtl(self) -> None:
        self._mode_command("rtl", self._rtl_mode)

    def _mode_command(self, what: str, mode: str) -> None:
        """A command that is a mode change (the set-point stream stops)."""
        with self._cmd_lock:
            self._require_link(what)
            self._clear_setpoint()
            self._set_mode(mode)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        """Send a velocity target now and keep resending it (never blocks: no ACK exists for it)."""
        check_velocity(vx, vy, vz, yaw_rate)
        self._require_link("set_velocity")
        now = self.clock()
        sp = self._rules.new(Frame(frame), float(vx), float(vy), float(vz), float(yaw_rate), now)
        with self._cond:
            verdict = self._rules.judge(self._v, sp, now)
            self._setpoint = self._rules.keep(sp) if verdict is Verdict.SEND else None
            if verdict is Verdict.WITHHOLD:
                self.setpoints_withheld += 1
                self._rate_log.log(
                    ("stale",),
                    logging.WARNING,
                    "velocity set-point withheld: nothing heard from the vehicle for %.1f s",
                    now - (self._v.rx_at or now),
                )
        if verdict is Verdict.SEND:
            self._send_setpoint(sp)

    def state(self) -> AutopilotState:
        with self._cond:
            if not self._connected:
                return AutopilotState(connected=False, link_age=math.inf)
            return self._v.autopilot_state(self.clock(), self._p.cells)

    # ----------------------------------------------------------------- extras (tools, tests)

    @property
    def target(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot talked to, once its HEARTBEAT was heard."""
        with self._cond:
            return self._target

    @property
    def home(self) -> tuple[float, float, float] | None:
        """Home (lat, lon in deg, altitude AMSL in m) from HOME_POSITION, if the autopilot sent it."""
        with self._cond:
            return self._v.home

    @property
    def resending(self) -> bool:
        """Whether a velocity set-point is currently being kept alive."""
        with self._cond:
            return self._setpoint is not None

    def ready_reasons(self) -> list[str]:
        """Why `arm` would still wait (empty when the vehicle is ready for GUIDED flight)."""
        with self._cond:
            return self._v.not_ready()

    # ----------------------------------------------------------------- link

    def _open(self) -> MavLink:
        try:
            return self._opener(self._p)
        except (OSError, ValueError) as exc:
            raise AutopilotError(f"cannot open {self.connection}: {exc}") from exc

    def _open_until(self, deadline: float) -> MavLink:
        """Open the link, retrying a refused TCP connection (SITL still starting) until `deadline`."""
        while True:
            try:
                return self._open()
            except AutopilotError as exc:
                if isinstance(exc.__cause__, ValueError):
                    raise  # a malformed connection string: retrying cannot help
                if self.clock() >= deadline or self._stop.wait(0.5):
                    raise AutopilotError(
                        f"{exc} (is SITL/the autopilot running, and is this the right port?)"
                    ) from exc.__cause__

    def _start_threads(self) -> None:
        self._workers.start(
            (self._receive_loop, f"mavlink-rx {self.connection}"),
            (self._transmit_loop, f"mavlink-tx {self.connection}"),
        )

    def _shutdown(self) -> None:
        self._stop.set()
        with self._cond:
            self._setpoint = None
            self._streams = None
            self._cond.notify_all()
        self._workers.halt()
        with self._send_lock:
            link, self._link = self._link, None
        if link is not None:
            with contextlib.suppress(OSError):
                link.close()

    def _require_link(self, what: str) -> None:
        if self._closed or self._link is None:
            raise AutopilotError(f"{what}: not connected")

    def _send(self, msg: Any) -> None:
        """Write one message; raises `AutopilotError` if the link cannot take it."""
        with self._send_lock:
            link = self._link
            if link is None:
                raise AutopilotError("not connected")
            try:
                link.send(msg)
            except OSError as exc:
                raise AutopilotError(f"cannot send on {self.connection}: {exc}") from exc

    def _target_or_default(self) -> tuple[int, int]:
        with self._cond:
            return self._target or (1, 1)

    # ----------------------------------------------------------------- receiving

    def _receive_loop(self) -> None:
        stop = self._stop
        while not stop.is_set():
            link = self._link
            if link is None:
                return
            try:
                msg = link.recv(_RX_POLL)
            except (OSError, ValueError) as exc:  # ValueError: select() on a socket closed by close()
                if stop.is_set():
                    return
                self._link_dropped(exc)
                continue
            if msg is not None:
                try:
                    self._on_message(msg)
                except Exception as exc:  # noqa: BLE001 - one odd message must not end reception
                    self._rate_log.log(
                        ("decode", msg.get_type()),
                        logging.WARNING,
                        "cannot use %s from the autopilot: %r",
                        msg.get_type(),
                        exc,
                    )

    def _link_dropped(self, exc: BaseException) -> None:
        """A stream link (TCP, serial) failed: reopen it until it comes back or we are closed."""
        self._rate_log.log(
            ("dropped",),
            logging.WARNING,
            "link %s failed (%s): reopening every %g s",
            self.connection,
            exc,
            _REOPEN_DELAY,
        )
        while not self._stop.wait(_REOPEN_DELAY):
            try:
                new = self._open()
            except AutopilotError as err:
                self._rate_log.log(("reopen",), logging.INFO, "%s", err)
                continue
            with self._send_lock:
                old, self._link = self._link, new
            if old is not None:
                with contextlib.suppress(OSError):
                    old.close()
            if self._stop.is_set():
                new.close()
                return
            log.info("link %s reopened", self.connection)
            self._rerequest_streams()  # a reopened stream link usually means a rebooted autopilot
            return

    def _on_message(self, msg: Any) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            if "signature" in str(getattr(msg, "reason", "")):
                self.signing_rejected += 1
                self._rate_log.log(
                    ("signature",),
                    logging.WARNING,
                    "message with a missing or wrong MAVLink 2 signature dropped (%d so far)",
                    self.signing_rejected,
                )
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        with self._cond:
            if self._target is None:
                if mtype != "HEARTBEAT" or not dialect.is_autopilot(
                    msg, self._p.target_system, self._p.target_component
                ):
                    return
                self._target = source
                self._check_autopilot_kind(msg)
            if source != self._target:
                return
            now = self.clock()
            stop = self._rules.stop_after_stale(self._v, now)
            if stop is not None:
                self._setpoint = None
            update = self._v.update(msg, now)
            if update.drop_setpoint:
                self._setpoint = None
            self._cond.notify_all()
        if update.request_streams:
            self._rerequest_streams()
        if stop is not None:
            log.warning(
                "link back after a stale spell: stopping the vehicle (zero velocity) until the HLC commands"
            )
            try:
                self._send_setpoint(stop)
            except AutopilotError as exc:
                self._rate_log.log(("resend",), logging.WARNING, "stop not sent: %s", exc)

    def _check_autopilot_kind(self, msg: Any) -> None:
        if self._warned_autopilot:
            return
        self._warned_autopilot = True
        kind, stack = self._autopilot_kind
        if msg.autopilot != kind:
            log.warning(
                "autopilot %s is not %s (MAV_AUTOPILOT %d): this adapter speaks %s's modes",
                self._target,
                stack,
                msg.autopilot,
                stack,
            )

    # ----------------------------------------------------------------- transmitting

    def _transmit_loop(self) -> None:
        next_heartbeat = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            if now >= next_heartbeat:
                next_heartbeat = max(next_heartbeat + self._heartbeat_period, now)
                try:
                    self._send(dialect.gcs_heartbeat())
                except AutopilotError as exc:
                    self._rate_log.log(("heartbeat",), logging.WARNING, "HEARTBEAT not sent: %s", exc)
            with self._cond:
                self._setpoint, verdict = self._rules.due(self._v, self._setpoint, now)
                if verdict is Verdict.WITHHOLD:
                    self.setpoints_withheld += 1  # never queue a set-point into a cut link
                due = self._setpoint if verdict is Verdict.SEND else None
                streams = self._streams
                requests = [] if streams is None else streams.step(self._v, self._target or (1, 1), now)
                if streams is not None and streams.done:
                    self._streams = None
            for msg in requests:
                try:
                    self._send(msg)
                except AutopilotError as exc:
                    self._rate_log.log(("streams",), logging.WARNING, "telemetry request failed: %s", exc)
                    with self._cond:
                        self._streams = None
                    break
            if due is not None:
                try:
                    self._send_setpoint(due)
                except AutopilotError as exc:
                    self._rate_log.log(("resend",), logging.WARNING, "velocity resend failed: %s", exc)
            with self._cond:
                sp, streams = self._setpoint, self._streams
                wake = min(
                    next_heartbeat,
                    math.inf if sp is None else sp.next_send,
                    math.inf if streams is None else streams.deadline,
                )
            self._stop.wait(min(max(wake - self.clock(), 0.005), 0.1))

    def _send_setpoint(self, sp: Setpoint) -> None:
        boot_ms = int(self.clock() * 1000)
        target = self._target_or_default()
        self._send(dialect.velocity_target(target, boot_ms, sp.frame, sp.vx, sp.vy, sp.vz, sp.yaw_rate))

    def _clear_setpoint(self) -> None:
        with self._cond:
            self._setpoint = None

    # ----------------------------------------------------------------- commands

    def _wait(self, predicate: Callable[[Vehicle], bool], timeout: float) -> bool:
        """Block until ``predicate(snapshot)`` holds (True) or `timeout` s pass (False); raises if closed."""
        deadline = self.clock() + timeout
        with self._cond:
            while True:
                if self._stop.is_set():
                    raise AutopilotError("closed while waiting for the autopilot")
                if predicate(self._v):
                    return True
                left = deadline - self.clock()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.1))

    def _command_result(self, command: int, *params: float, attempts: int = 2) -> int | None:
        """Send COMMAND_LONG `command`, return its COMMAND_ACK's MAV_RESULT (None: never acknowledged)."""
        for confirmation in range(attempts):
            with self._cond:
                mark = self._v.messages
                target = self._target or (1, 1)
            self._send(dialect.command_long(target, command, confirmation, *params))

            def acked(v: Vehicle, mark: int = mark) -> bool:
                return v.ack_after(command, mark) is not None

            if self._wait(acked, self._ack_timeout):
                with self._cond:
                    return self._v.acks[command][0]
            log.debug(
                "%s: no COMMAND_ACK after %g s (attempt %d)",
                cmd_name(command),
                self._ack_timeout,
                confirmation + 1,
            )
        return None

    def _command(self, command: int, *params: float) -> int:
        result = self._command_result(command, *params)
        if result is None:
            raise AutopilotError(
                f"{cmd_name(command)}: no COMMAND_ACK from {self.connection} "
                f"(2 attempts, {self._ack_timeout:g} s each)"
            )
        return result

    def _set_mode(self, name: str) -> None:
        """Switch to ArduCopter mode `name` and confirm it by a HEARTBEAT received after the ACK."""
        number, params = self._mode_request(name)
        with self._cond:
            mark = self._v.messages
            self._v.commanded = (name, self.clock())
        result = self._command_result(mav.MAV_CMD_DO_SET_MODE, *params)
        if result == mav.MAV_RESULT_UNSUPPORTED:
            result = self._set_mode_message(number)  # the SET_MODE message: older firmware
        if result is None:
            raise AutopilotError(
                f"mode {name}: no COMMAND_ACK from {self.connection} "
                f"(2 attempts, {self._ack_timeout:g} s each)"
            )
        if result != mav.MAV_RESULT_ACCEPTED:
            raise AutopilotError(f"mode {name} refused ({result_name(result)}){self._because(mark)}")
        with self._cond:
            acks = self._v.acks
            ack_at = max(
                at
                for cmd, (_, at) in acks.items()
                if cmd in (mav.MAV_CMD_DO_SET_MODE, SET_MODE_ACK) and at > mark
            )
        if not self._wait(lambda v: v.heartbeat_msg > ack_at and v.custom_mode == number, self._mode_timeout):
            with self._cond:
                shown = self._v.mode
            raise AutopilotError(
                f"mode {name} acknowledged but HEARTBEAT still shows {shown} after {self._mode_timeout:g} s"
            )
        log.info("mode %s confirmed", name)

    def _mode_request(self, name: str) -> tuple[int, tuple[float, ...]]:
        """(the HEARTBEAT ``custom_mode`` of mode `name`, MAV_CMD_DO_SET_MODE's parameters for it)."""
        number = COPTER_MODES[name]
        return number, (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)

    def _set_mode_message(self, number: int) -> int | None:
        with self._cond:
            mark = self._v.messages
            target_system = (self._target or (1, 1))[0]
        self._send(dialect.set_mode(target_system, number))
        if self._wait(lambda v: v.ack_after(SET_MODE_ACK, mark, final=False) is not None, self._ack_timeout):
            with self._cond:
                return self._v.acks[SET_MODE_ACK][0]
        return None

    def _wait_ready(self) -> None:
        timeout = self._p.ready_timeout
        with self._cond:
            reasons = self._v.not_ready()
        if reasons:
            log.info("waiting up to %g s before arming: %s", timeout, "; ".join(reasons))
        if not self._wait(lambda v: not v.not_ready(), timeout):
            with self._cond:
                reasons = self._v.not_ready()
            raise AutopilotError(f"not ready to arm after {timeout:g} s: {'; '.join(reasons)}")

    def _rerequest_streams(self) -> None:
        """Ask for the streams again; the transmit thread sends the requests (nothing here waits)."""
        if not self._connected:
            return  # connect() is asking anyway
        with self._cond:
            self._streams = StreamRequest(self._p.stream_rate_hz, self._ack_timeout)

    def _request_streams(self) -> None:
        """Ask for the telemetry `state` needs (`streams.StreamRequest`), waiting for each answer."""
        req = StreamRequest(self._p.stream_rate_hz, self._ack_timeout)
        while True:
            with self._cond:
                msgs = req.step(self._v, self._target or (1, 1), self.clock())
            for msg in msgs:
                self._send(msg)
            if req.done:
                return
            self._wait(req.answered, max(req.deadline - self.clock(), 0.0))

    # ----------------------------------------------------------------- vehicle parameters

    def read_params(
        self, names: tuple[str, ...] | list[str], groups: tuple[tuple[str, ...], ...] | None = None
    ) -> dict[str, float]:
        """The named parameters the vehicle reports (PARAM_REQUEST_READ, two rounds); absent ones are left out.

        All requests go out at once and the answers are collected together, so a slow radio costs two
        ``ack_timeout`` at most, not one per parameter. The read is complete when one name of each of
        `groups` arrived (default: every name); a firmware without a parameter never answers for it.
        """
        groups = tuple((n,) for n in names) if groups is None else groups
        with self._cond:
            mark = self._v.messages

        def complete(v: Vehicle) -> bool:
            return all(any(v.param_after(n, mark) for n in group) for group in groups)

        wanted = list(names)
        for _ in range(2):
            target = self._target_or_default()
            for name in wanted:
                self._send(dialect.param_request_read(target, name))
            self._wait(complete, self._ack_timeout)
            with self._cond:
                if complete(self._v):
                    break
                wanted = [n for n in names if not self._v.param_after(n, mark)]
        with self._cond:
            return {n: self._v.params[n] for n in names if self._v.param_after(n, mark)}

    def set_param(self, name: str, value: float) -> None:
        """PARAM_SET `name` and wait for the PARAM_VALUE that confirms it; `AutopilotError` otherwise."""
        with self._cond:
            ptype = self._v.param_types.get(name, mav.MAV_PARAM_TYPE_REAL32)
        for _ in range(2):
            with self._cond:
                mark = self._v.messages
                target = self._target or (1, 1)
            self._send(dialect.param_set(target, name, self._param_wire_value(value, ptype), ptype))

            def confirmed(v: Vehicle, mark: int = mark) -> bool:
                return v.param_after(name, mark) and abs(v.params[name] - value) <= 1e-3 * max(
                    1.0, abs(value)
                )

            if self._wait(confirmed, self._ack_timeout):
                log.warning("vehicle parameter %s set to %g (configure_vehicle)", name, value)
                return
        with self._cond:
            shown = self._v.params.get(name)
        raise AutopilotError(
            f"PARAM_SET {name} = {value:g} not confirmed by the vehicle (it reports {shown})"
        )

    #: The failsafe parameters the pre-flight check reads, and the groups that make a read complete.
    _failsafe_params: ClassVar[tuple[tuple[str, ...], tuple[tuple[str, ...], ...]]] = (
        vehicle_checks.READ,
        vehicle_checks.REQUIRED_GROUPS,
    )

    def _findings(self, values: dict[str, float]) -> list[Finding]:
        """What the pre-flight check finds in the failsafe parameter `values` read from the vehicle."""
        p = self._p
        return vehicle_checks.check(
            values, source_system=self.source_system, max_guid_timeout=p.max_guid_timeout, cells=p.cells
        )

    def _param_wire_value(self, value: float, param_type: int) -> float:
        """The float PARAM_SET carries for `value` (ArduPilot: the value itself; PX4 packs integers)."""
        return float(value)

    def _check_vehicle(self) -> list[Finding]:
        """The pre-flight check of the vehicle's own failsafes (module docstring); the findings left."""
        p = self._p
        names, groups = self._failsafe_params
        values = self.read_params(names, groups)
        findings = self._findings(values)
        if p.configure_vehicle and any(f.settable for f in findings):
            for f in findings:
                if f.settable and f.want is not None:
                    try:
                        self.set_param(f.param, f.want)
                    except AutopilotError as exc:
                        log.warning("%s", exc)
            values = self.read_params(names, groups)
            findings = self._findings(values)
        for f in findings:
            log.warning("vehicle pre-flight check: %s", f.text())
        if not findings:
            log.info(
                "vehicle pre-flight check: failsafe parameters OK (%s)",
                ", ".join(f"{k}={v:g}" for k, v in sorted(values.items())),
            )
        self.vehicle_findings = findings
        self._vehicle_ok = not findings
        return findings

    # ----------------------------------------------------------------- STATUSTEXT reasons

    def _because(self, mark: int) -> str:
        with self._cond:
            reason = self._v.texts_since(mark)
        return f": {reason}" if reason else ""
