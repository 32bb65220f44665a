"""`SimAdapter`: the `VehicleAdapter` contract over the simulated quadcopter (`physics`, `faults`).

In-process and never blocking: every command integrates the model up to now (`Quadcopter._advance`)
and acts on it at once, as ArduCopter in GUIDED would: ``arm`` refuses on an empty battery or when
told to (`FaultInjection.set_refuse_arm`), ``takeoff`` needs GUIDED and arming, velocity set-points
are ignored outside GUIDED flight, and a lost link makes every command raise.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.strict import validate_strict
from antalate_lcm.vehicles.base import (
    AutopilotError,
    Clock,
    Frame,
    VehicleAdapter,
    VehicleState,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.vehicles.sim.faults import FaultInjection
from antalate_lcm.vehicles.sim.params import Params
from antalate_lcm.vehicles.sim.persistence import StateFile
from antalate_lcm.vehicles.sim.physics import M_CLIMB, M_DESCEND, M_GUIDED, M_RETURN
from antalate_lcm.vehicles.sim.telemetry import snapshot

__all__ = ["SimAdapter"]


class SimAdapter(FaultInjection, VehicleAdapter):
    """A kinematic quadcopter: its model in `physics`, its fault injection in `faults`."""

    name = "sim"
    blocking = False  # in-process: every command returns at once
    params_model = Params
    # With `VehicleAdapter`'s two attributes, the sim has no __dict__: its ``clock``, read by every
    # poll and command, is a slot as the model's state (a subclass may add attributes freely).
    __slots__ = ("_state_file", "params", "clock")

    def __init__(self, params: Mapping[str, Any] | None = None, *, clock: Clock = time.monotonic) -> None:
        super().__init__(params, clock=clock)
        # Checked as at config load (a StrictError naming the key); a subclass without a model of
        # its own still gets the sim's.
        checked = self.validate_params(self.params)
        p = checked if isinstance(checked, Params) else validate_strict(Params, dict(self.params))
        self._init_state(p, clock())
        self._state_file = StateFile(p.state_file) if p.state_file else None

    # ----------------------------------------------------------------- Vehicle adapter contract

    def connect(self) -> None:
        if self._state_file is not None:
            self._state_file.restore(self)
        self._advance()
        self._connected = True

    def close(self) -> None:
        self._connected = False

    def arm(self) -> bool:
        self._command("arm")
        if self._refuse_arm or self.battery <= 0.0:
            return False
        if not self.armed:
            self.mode = "GUIDED"
            self._failsafe = ""
            self.armed = True
            self._armed_since = self._sim_time
            self._disarm_at = None
        return True

    def disarm(self) -> None:
        self._command("disarm")
        if self.in_air:
            raise AutopilotError("disarm refused: vehicle in the air")
        self._disarm()

    def takeoff(self, alt: float) -> None:
        self._command("takeoff")
        check_takeoff_altitude(alt)
        if not self.armed:
            raise AutopilotError("takeoff refused: not armed")
        if self.mode != "GUIDED":
            raise AutopilotError(f"takeoff refused: mode {self.mode}, needs GUIDED")
        if self.in_air:
            raise AutopilotError("takeoff refused: already flying")
        self.in_air = True
        self._takeoff_alt = alt
        self._armed_since = None
        self._airborne_since = self._sim_time
        self._phase = M_CLIMB

    def land(self) -> None:
        self._command("land")
        self._switch_mode("LAND", M_DESCEND)

    def rtl(self) -> None:
        self._command("rtl")
        self._switch_mode("RTL", M_RETURN)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        self._command("set_velocity")
        if not math.isfinite(vx + vy + vz + yaw_rate):  # finite, all four (a swarm's 10 Hz): no tuple
            check_velocity(vx, vy, vz, yaw_rate)  # the verdict (a sum can overflow)
        if self.mode != "GUIDED" or self._phase is not M_GUIDED:
            return  # like ArduCopter: velocity targets are ignored outside GUIDED flight
        self._cmd = (vx, vy, vz, yaw_rate, frame if frame.__class__ is Frame else Frame(frame))
        self._cmd_time = self._sim_time

    def state(self) -> VehicleState:
        self._advance()
        if self._ends or self._scheduled:  # most sims schedule no fault: no call 20 times a second
            self._scheduled_faults()
        if self._state_file is not None and self._connected:
            self._state_file.save(self)
        if self._state_error is not None:
            raise RuntimeError(self._state_error)
        if not self._connected:
            return VehicleState(connected=False, link_age=math.inf)
        if self._link_lost_at is not None:
            frozen = self._frozen if self._frozen is not None else snapshot(self)
            if math.isinf(frozen.link_age):
                return frozen  # never heard from at all
            return replace(frozen, link_age=max(0.0, self.clock() - self._link_lost_at))
        return snapshot(self)

    def _command(self, what: str) -> None:
        self._advance()
        if not self._connected:
            raise AutopilotError(f"{what}: not connected")
        if self._link_lost_at is not None:
            raise AutopilotError(f"{what}: no response from the vehicle (link lost)")


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
