"""`MavlinkConnection`: the link to the autopilot and the two threads that keep the vehicle's picture.

The adapter is a small ground station: it speaks pymavlink over serial, UDP or TCP and keeps its own
picture of the vehicle (`vehicle.Vehicle`) from the telemetry the autopilot streams. This module is
that ground station's I/O; `commands` asks the vehicle for things, `adapter` is the HLC's contract.

Threads
-------
``connect()`` opens the link (`link.MavLink`: pymavlink's connection, or a `link.MemoryLink` given
as ``link=``) and starts a receive thread (decodes everything, keeps the `vehicle.Vehicle` picture under
a lock, wakes the command waiters) and a transmit thread (our HEARTBEAT, the velocity resend, and the
telemetry re-request after a reboot or a reopened link: no thread is started for it). A TCP or serial
link that drops is reopened by the receive thread every second until `close`. The rules themselves are
pure: `dialect` (modes, names, messages), `vehicle` (telemetry into the picture, ACK matching),
`setpoints` (when a velocity target may go out) and `streams` (the telemetry requests).

Velocity targets expire after GUID_TIMEOUT (3 s) in GUIDED
----------------------------------------------------------
The transmit thread resends the current set-point ``velocity_resend_hz`` times a second while the copter
flies in GUIDED -- but **never one older than ``setpoint_timeout``** (counted from the HLC's
`set_velocity` call) and **never while the link is stale** (no message from the vehicle for
``link_stale_after``): a TCP link or a buffering radio keeps what is written during a cut and delivers it
all when the link returns, and a field trial flew 6.1 m on such a backlog while the HLC said LLC_DOWN.
When messages flow again after a stale spell, a zero set-point goes out at once, so it reaches the vehicle
right behind any backlog and stops it (`setpoints`).

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
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
from collections.abc import Callable
from typing import Any, ClassVar

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.kit import LinkedAdapter
from antalate_lcm.vehicles.mavlink import dialect
from antalate_lcm.vehicles.mavlink.link import MavLink, PymavlinkLink
from antalate_lcm.vehicles.mavlink.params import Params
from antalate_lcm.vehicles.mavlink.setpoints import Setpoint, SetpointRules, Verdict
from antalate_lcm.vehicles.mavlink.signing import signing_key
from antalate_lcm.vehicles.mavlink.streams import StreamRequest
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle

log = logging.getLogger("antalate.autopilot.mavlink")

__all__ = ["MavlinkConnection"]

_REOPEN_DELAY = 1.0  # s between attempts to reopen a dropped TCP/serial link
_RX_POLL = 0.1  # s the receive thread blocks at most, so close() is prompt


class MavlinkConnection(LinkedAdapter[Params, MavLink]):
    """The link, the receive and transmit threads, and the vehicle's picture under ``_cond``.

    The base of `adapter.MavlinkAdapter` (through `commands.MavlinkCommands`); it holds no command
    of the HLC's. ``link`` opens the link instead of pymavlink's connection (a `link.MemoryLink` in tests).
    """

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
        #: Messages dropped for a missing or wrong MAVLink 2 signature (with ``signing_key``).
        self.signing_rejected = 0
        #: Set-points not sent because they were too old or the link was stale.
        self.setpoints_withheld = 0

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

    # ----------------------------------------------------------------- waiting on the picture, telemetry

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
