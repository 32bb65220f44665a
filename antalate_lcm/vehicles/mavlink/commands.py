"""`MavlinkCommands`: what the adapter asks of the vehicle, and the answer it waits for.

* Every COMMAND_LONG is matched to its COMMAND_ACK by command id (only one command is in flight at a
  time); a command without ACK is sent once more (``confirmation`` 1) before `AutopilotError`.
* **A mode set while the autopilot is still booting is acknowledged, then silently reverted** when
  initialisation ends (ArduCopter). So `arm` first waits for HEARTBEAT ``system_status`` STANDBY, and
  every mode change is confirmed by a HEARTBEAT received *after* the COMMAND_ACK showing the new
  ``custom_mode``. A firmware that does not know MAV_CMD_DO_SET_MODE gets the SET_MODE message.

Vehicle pre-flight checks
-------------------------
On connect the adapter reads the vehicle's own failsafe parameters (`vehicle_checks`: FS_GCS_ENABLE,
SYSID_MYGCS, GUID_TIMEOUT, FENCE_*, BATT_*) with PARAM_REQUEST_READ. Each one that leaves the vehicle
unprotected is written (PARAM_SET, confirmed by PARAM_VALUE) when ``configure_vehicle`` is set, and
otherwise logged as a warning with the exact value to set; with ``require_vehicle_failsafes`` `arm`
returns False and `last_refusal` names the parameter (the HLC puts it into its ``hlc_error_t``).
"""

from __future__ import annotations

import logging
from typing import ClassVar

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.mavlink import dialect, vehicle_checks
from antalate_lcm.vehicles.mavlink.connection import MavlinkConnection
from antalate_lcm.vehicles.mavlink.dialect import COPTER_MODES, SET_MODE_ACK, cmd_name, result_name
from antalate_lcm.vehicles.mavlink.vehicle import Vehicle
from antalate_lcm.vehicles.mavlink.vehicle_checks import Finding

log = logging.getLogger("antalate.autopilot.mavlink")

__all__ = ["MavlinkCommands"]


class MavlinkCommands(MavlinkConnection):
    """COMMAND_LONG and its ACK, confirmed mode changes, parameter reads and writes, the pre-flight check."""

    def _setup(self) -> None:
        super()._setup()
        #: What the last vehicle pre-flight check found (empty: the vehicle's failsafes protect it).
        self.vehicle_findings: list[Finding] = []
        self._vehicle_ok = False  # the last pre-flight check found nothing

    # ----------------------------------------------------------------- commands and modes

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
