"""The ``[hlc.autopilot_params]`` of ``autopilot = "sim"``: every knob of the model and its faults.

Closed, strict and finite as every adapter's (`antalate_lcm.vehicles.kit.params`): validated when the
config is loaded (`VehicleAdapter.params_model`), so a negative delay or rate, a battery over 100 % or
``link_loss = "yes"`` stops the program naming the key. docs/simulator.md explains the dynamics the
numbers set.
"""

from __future__ import annotations

from typing import Any, Literal, TypeVar

from pydantic import Field

from antalate_lcm.base.shared import shared_value
from antalate_lcm.vehicles.kit.params import AdapterParams, defaults

T = TypeVar("T", bound=tuple[Any, ...])

__all__ = ["DEFAULTS", "Params", "shared"]


class Params(AdapterParams):
    """Every sim parameter with its default (`DEFAULTS` by name)."""

    # Where it starts.
    home_lat: float = Field(32.7767, ge=-90, le=90, description="deg; Technion, Haifa")
    home_lon: float = Field(35.0231, ge=-180, le=180, description="deg")
    heading: float = Field(0.0, description="deg, initial")
    battery: float = Field(100.0, ge=0, le=100, description="percent, initial")
    # How it flies (`physics`, docs/simulator.md).
    tau: float = Field(0.5, gt=0, description="s, time constant of the velocity response")
    climb_rate: float = Field(2.5, gt=0, description="m/s")
    descent_rate: float = Field(1.5, gt=0, description="m/s")
    max_speed: float = Field(10.0, gt=0, description="m/s horizontal")
    max_yaw_rate: float = Field(180.0, ge=0, description="deg/s")
    rtl_speed: float = Field(5.0, gt=0, description="m/s")
    rtl_altitude: float = Field(0.0, ge=0, description="m; 0 = return at the current altitude")
    velocity_hold: float = Field(3.0, gt=0, description="s a velocity set-point stays valid")
    #: > 0: at 0 the vehicle would disarm between arm() and takeoff().
    auto_disarm_delay: float = Field(10.0, gt=0, description="s armed on the ground before disarming")
    land_disarm_delay: float = Field(0.5, ge=0, description="s after touchdown")
    time_scale: float = Field(1.0, gt=0, description="simulated seconds per real second")
    max_step: float = Field(0.05, gt=0, description="s of simulated time per integration step")
    # Its battery (the voltage model: `telemetry`).
    drain_flying: float = Field(4.0, ge=0, description="percent per minute in the air")
    drain_idle: float = Field(0.1, ge=0, description="percent per minute on the ground")
    cells: int = Field(4, ge=0, le=14, description="cells in series; 0 = the vehicle reports no voltage")
    voltage_sag: float = Field(0.0, ge=0, description="V per cell lost under load in the air")
    battery_warning_at: float = Field(
        0.0, ge=0, le=100, description="percent at or below which the vehicle warns; 0 = never"
    )
    # Faults from the start (`faults`).
    link_loss: bool = Field(False, description="the vehicle never answers")
    refuse_arm: bool = Field(False, description="arm() returns False")
    takeover_autoland: bool = Field(True, description="after pilot_takeover(), the pilot lands")
    takeover_land_delay: float = Field(2.0, ge=0, description="s")
    # Scheduled faults, in s of flight after takeoff (0 = never), for tests that run the sim in
    # another process where the fault-injection methods cannot be called (`faults`).
    link_loss_after: float = Field(0.0, ge=0, description="s of flight")
    link_loss_for: float = Field(0.0, ge=0, description="s the scheduled link loss lasts; 0 = for good")
    takeover_after: float = Field(0.0, ge=0, description="s of flight")
    failsafe_after: float = Field(0.0, ge=0, description="s of flight")
    failsafe_mode: Literal["rtl", "land", "brake"] = Field("rtl", description="of the scheduled failsafe")
    failsafe_reason: str = Field("fence breach", description="of the scheduled failsafe")
    state_error_after: float = Field(0.0, ge=0, description="s of flight")
    state_error_for: float = Field(0.0, ge=0, description="s state() keeps raising; 0 = for good")
    # A file where the vehicle's state is kept, so that a restarted HLC process finds the vehicle
    # where it was (a real vehicle outlives the software that flies it; `persistence`).
    state_file: str = Field("", description='path of the persisted state; "" = none')


#: Parameters and their defaults, by name.
DEFAULTS: dict[str, Any] = defaults(Params)


def shared(values: T) -> T:
    """The process's one tuple of these parameters to the bit (-0.0 is not 0.0, 1 is not 1.0): a
    thousand sims of one config read one object on every poll (`shared_value`, keyed by repr)."""
    return shared_value(values, key=(tuple, repr(values)))
