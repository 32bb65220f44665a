"""`CrazyflieConnection`: cflib's link to the Crazyflie, its log blocks and their reopening.

* **State** comes from three log blocks (`telemetry.LOG_BLOCKS`): the state estimator's pose and
  velocity, yaw, battery (``pm.vbat``, ``pm.batteryLevel``, ``pm.state``), the supervisor's bitfield
  (armed, flying, tumbled, locked) and the Kalman position variances. The link age is the time since
  the last packet of any kind (log data, or the answers to cflib's 10 Hz latency pings).
* **The firmware answers every high-level packet** (crazyflie-firmware 2026.08
  crtp_commander_high_level.c ``crtpCommanderHighLevelTask``): `_on_hl_answer` clears the command
  the control loop is waiting for (`control`) and records a refusal.
* **Shutdown in the air**: `close` sends an emergency stop (motors off) before closing the link:
  nothing would command the vehicle any more (under the high-level commander it would hover until its
  battery is empty). Every other close -- a failed connection or reconnection -- avoids cflib's
  parting zero-thrust set-point, which would drop a flying Crazyflie (`_close_quietly`).
* **cflib closing the link**: its radio driver gives up after 100 un-acknowledged packets in a row
  ("Too many packets lost", cflib 0.1.34 crtp/radiodriver.py ``_nr_of_retries``) and closes the
  link for good; the adapter reopens it every ``_RECONNECT_S`` until the Crazyflie answers, so a
  radio outage is the HLC's recoverable LLC_DOWN, not the end of the agent. Meanwhile the control
  loop keeps its timers (`control`).
* Several adapters in one process on one Crazyradio share it through cflib's radio manager, as
  cflib's ``Swarm`` does.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.crazyflie.params import Params
from antalate_lcm.vehicles.crazyflie.telemetry import LOG_BLOCKS, Reading, apply_log
from antalate_lcm.vehicles.kit import LinkAge, LinkedAdapter

log = logging.getLogger("antalate.autopilot.crazyflie")

__all__ = ["CFLIB_MISSING", "CrazyflieConnection"]

CFLIB_MISSING = (
    "the crazyflie autopilot needs Bitcraze's cflib, which is not installed: "
    "pip install 'antalate[crazyflie]'"
)

_RECONNECT_S = 2.0  # s between attempts to reopen a link cflib closed
#: cflib's high-level commander command bytes (crtp_commander_high_level.c TrajectoryCommand_e)
_HL_TAKEOFF, _HL_LAND, _HL_GOTO = 7, 8, 12
_HL_PORT = 8  # CRTP_PORT_SETPOINT_HL

_drivers_lock = threading.Lock()
_drivers_ready = False


def _init_drivers() -> None:
    """cflib's drivers, once per process (``init_drivers`` appends to a global list each call).

    ``memory://`` (`memory.MemoryDriver`, a peer in this process) comes last, after cflib's own.
    """
    global _drivers_ready
    import cflib.crtp

    from antalate_lcm.vehicles.crazyflie import memory

    with _drivers_lock:
        if not _drivers_ready:
            cflib.crtp.init_drivers()
            _drivers_ready = True
    memory.install()


class CrazyflieConnection(LinkedAdapter[Params, Any]):
    """The cflib link (``_cf``), what it reports (``_reading``, the link age) and its reopening.

    The base of `adapter.CrazyflieAdapter` (through `control.CrazyflieControl`): no command of the
    HLC's is here. Its state is guarded by ``_lock``.
    """

    def _setup(self) -> None:
        """The constructor's ``link=`` makes the cflib ``Crazyflie`` for each connection (default: cflib's
        own, its drivers installed, `_default_link`)."""
        self._lock = threading.RLock()
        self._cf: Any = None
        self._reading = Reading()
        self._heard = LinkAge(self.clock)  # any packet: log data, or the answers to cflib's latency pings
        self._connected = False
        self._no_kalman = False
        self._link_error = ""
        #: RTL's target: the take-off point, else where the vehicle was first seen on the ground, else
        #: (an HLC restarted in the air) the frame's origin.
        self._home: tuple[float, float] | None = None
        #: the high-level command that set the mode, until the firmware answers it: (command byte,
        #: when sent, how to send it again); resent by the control loop (`control`)
        self._hl_pending: tuple[int, float, str] | None = None
        self._hl_refused: tuple[int, int] | None = None  # (command byte, result) of the last refusal
        self._takeoff_accepted = False  # the firmware answered the last take-off 0 (its planner took it)
        self._reconnecting = False
        self._reconnect_at = -math.inf
        self.reconnects = 0

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

    def _require_link(self) -> Any:
        with self._lock:
            cf = self._cf
            if cf is None or not self._connected:
                raise AutopilotError(
                    f"not connected to the Crazyflie at {self._p.uri}"
                    + (f" ({self._link_error})" if self._link_error else "")
                )
            return cf
