"""`Px4Adapter`: PX4 over MAVLink -- SITL or a flight controller -- through the MAVLink adapter's machinery.

The link, MAVLink 2 signing, the receive and transmit threads, telemetry requests, COMMAND_ACK matching,
parameter reads and the link-loss rules are `antalate_lcm.vehicles.mavlink.MavlinkAdapter`'s; this
subclass speaks PX4 where PX4 differs from ArduCopter (PX4 v1.15.4, sources cited in each module):

* **Modes** are PX4's (main, sub) pairs (`modes`), set with MAV_CMD_DO_SET_MODE and confirmed by a
  HEARTBEAT received after the COMMAND_ACK, as for ArduCopter.
* **Readiness** is PX4's own pre-arm verdict (SYS_STATUS's PREARM_CHECK health bit), HOME_POSITION,
  ESTIMATOR_STATUS and a 3D fix (`vehicle.Px4Vehicle.not_ready`); PX4 SITL needs ~40 s after boot.
* **Arming** happens in Hold (AUTO.LOITER, the mode PX4 boots in); **take-off** is MAV_CMD_NAV_TAKEOFF
  with an AMSL altitude (home's altitude + the HLC's height; PX4's navigator reads param7 as AMSL,
  src/modules/navigator/takeoff.cpp) and PX4 ends it in Hold on its own.
* **Velocities** fly in OFFBOARD: the set-point stream starts ``offboard_lead`` s before the adapter asks
  for OFFBOARD (PX4 refuses the switch without it), then runs continuously, zero once the HLC's
  set-point is ``setpoint_timeout`` old (`offboard.OffboardRules`). The switch is made by a short-lived
  thread so `set_velocity` never blocks.
* **Hold, RTL and LAND** are PX4's AUTO.LOITER, AUTO.RTL and AUTO.LAND.
* **Who changed the mode**: the adapter's commands (and PX4's own end of our take-off) are ours; a mode
  PX4 enters with its failsafe flag (HEARTBEAT ``system_status`` CRITICAL) is a failsafe's, named by
  `failsafe`; anything else is a pilot's or another ground station's.
* **Vehicle checks** read COM_OF_LOSS_T, COM_OBL_RC_ACT, NAV_DLL_ACT, COM_DL_LOSS_T, COM_FAIL_ACT_T,
  COM_LOW_BAT_ACT and GF_ACTION (`vehicle_checks`), and with ``configure_vehicle`` write what is wrong
  (PX4 packs integer parameters byte-wise into PARAM_SET's float).
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, ClassVar

from pydantic import BaseModel
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.vehicles.base import AutopilotError, Frame
from antalate_lcm.vehicles.mavlink.adapter import MavlinkAdapter
from antalate_lcm.vehicles.mavlink.vehicle_checks import Finding
from antalate_lcm.vehicles.px4 import modes, vehicle_checks
from antalate_lcm.vehicles.px4.offboard import OffboardRules
from antalate_lcm.vehicles.px4.params import Px4Params
from antalate_lcm.vehicles.px4.vehicle import Px4Vehicle, encode_param

log = logging.getLogger("antalate.autopilot.px4")

__all__ = ["Px4Adapter"]


class Px4Adapter(MavlinkAdapter):
    """PX4 through pymavlink; see the module docstring. ``link`` as for `MavlinkAdapter`."""

    name = "px4"
    params_model: ClassVar[type[BaseModel]] = Px4Params
    _arm_mode = modes.HOLD
    _land_mode = "AUTO.LAND"
    _rtl_mode = "AUTO.RTL"
    _vehicle_class = Px4Vehicle
    _autopilot_kind = (mav.MAV_AUTOPILOT_PX4, "PX4")

    def _setup(self) -> None:
        super()._setup()
        p = self._p
        assert isinstance(p, Px4Params)
        self._px4 = p
        self._rules = OffboardRules(
            resend_period=1.0 / p.velocity_resend_hz,
            timeout=p.setpoint_timeout,
            stale_after=p.link_stale_after,
            lead=p.offboard_lead,
        )
        self._offboard_rules = self._rules
        self._streaming_since: float | None = None  # when the stream towards an OFFBOARD switch began
        self._switching = False  # a switch thread is running

    # ----------------------------------------------------------------- Vehicle adapter contract

    def _enter_arm_mode(self) -> None:
        """Arming happens in Hold, the mode PX4 boots in: switch only when it is elsewhere."""
        with self._cond:
            mode = self._v.mode
        if mode != modes.HOLD:
            self._set_mode(modes.HOLD)

    def _armed_in(self, mode: str) -> None:
        self._px4v.ours = mode == modes.HOLD

    def _takeoff_target(self, alt: float) -> tuple[tuple[float, ...], str]:
        """Home + `alt`, AMSL as PX4's navigator reads param7; PX4 holds there when it arrives (lock held)."""
        home = self._v.home
        self._v.commanded = ("AUTO.TAKEOFF", self.clock())
        if home is None:
            raise AutopilotError(
                "takeoff refused: PX4 has sent no HOME_POSITION (needed for an AMSL altitude)"
            )
        amsl = home[2] + float(alt)
        nan = float("nan")
        return (-1, 0, 0, nan, nan, nan, amsl), f"{alt:g} m ({amsl:.2f} m AMSL)"

    def hold(self) -> None:
        """Hold position in PX4's Hold (AUTO.LOITER); the set-point stream stops."""
        self._mode_command("hold", modes.HOLD)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        """Stream the set-point (never blocks); from our Hold, switch to OFFBOARD once it has run ``offboard_lead``."""
        super().set_velocity(vx, vy, vz, yaw_rate, frame)
        now = self.clock()
        with self._cond:
            sp = self._setpoint
            if sp is None or self._v.mode == "OFFBOARD":
                self._streaming_since = None
                return
            if self._streaming_since is None:
                self._streaming_since = now
            start = not self._switching
            self._switching = True
        if start:
            threading.Thread(target=self._switch_to_offboard, name="px4-offboard", daemon=True).start()

    # ----------------------------------------------------------------- OFFBOARD

    @property
    def _px4v(self) -> Px4Vehicle:
        v = self._v
        assert isinstance(v, Px4Vehicle)
        return v

    def _armed_ours(self) -> bool:
        return self._px4v.ours

    def _switch_to_offboard(self) -> None:
        """Wait until the stream has run ``offboard_lead`` s, then ask for OFFBOARD (once; the HLC's next
        set-point starts another attempt if this one fails)."""
        try:
            while not self._stop.is_set():
                with self._cond:
                    sp, since = self._setpoint, self._streaming_since
                    due = self._offboard_rules.switch_due(self._v, sp, since, self.clock())
                    give_up = sp is None or sp.zero or self._v.mode == "OFFBOARD"
                if give_up:
                    return
                if due:
                    break
                self._stop.wait(0.05)
            else:
                return
            with self._cmd_lock:
                with self._cond:
                    if self._setpoint is None or not self._px4v.ours:
                        return
                try:
                    self._set_mode("OFFBOARD")
                except AutopilotError as exc:
                    log.warning("OFFBOARD not entered: %s", exc)
                    with self._cond:
                        self._setpoint = None
        finally:
            with self._cond:
                self._switching = False
                self._streaming_since = None

    # ----------------------------------------------------------------- modes and parameters

    def _mode_request(self, name: str) -> tuple[int, tuple[float, ...]]:
        main, sub = modes.COMMANDS[name]
        return modes.pack(main, sub), (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)

    def _param_wire_value(self, value: float, param_type: int) -> float:
        return encode_param(value, param_type)

    _failsafe_params = (vehicle_checks.READ, vehicle_checks.REQUIRED_GROUPS)

    def _findings(self, values: dict[str, float]) -> list[Finding]:
        if "COM_DL_LOSS_T" in values:  # when PX4's data-link-loss failsafe fires (`failsafe`)
            with self._cond:
                self._px4v.datalink_loss_after = values["COM_DL_LOSS_T"]
        return vehicle_checks.check(values, max_offboard_loss_timeout=self._px4.max_offboard_loss_timeout)


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
