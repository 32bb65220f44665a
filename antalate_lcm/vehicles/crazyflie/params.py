"""The ``[hlc.autopilot_params]`` of the ``crazyflie`` adapter, validated before any I/O.

Closed, strict and finite as every adapter's (`antalate_lcm.vehicles.kit.params`), so a field config
fails at start-up naming the key instead of flying on a default. docs/crazyflie.md has the same table
for people.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator, model_validator

from antalate_lcm.vehicles.kit.params import AdapterParams, defaults, require_duration

#: The Crazyflie firmware's commander watchdog (supervisor.c): no set-point for 0.5 s levels the
#: vehicle, 2 s stops the motors. A streamed set-point must be renewed well inside the first.
WDT_STABILIZE_S = 0.5

_URI_SCHEMES = ("radio://", "usb://", "udp://", "tcp://", "serial://", "memory://")


class Params(AdapterParams):
    """Every adapter parameter with its default and, beside it, its meaning."""

    # cflib link URI: radio://, usb://, udp://, memory:// (a peer in this process)
    uri: str = "radio://0/80/2M/E7E7E7E7E7"
    origin_lat: float = Field(32.7767, ge=-90.0, le=90.0)  # deg: WGS84 of the local frame's origin
    origin_lon: float = Field(35.0231, ge=-180.0, le=180.0)  # deg
    origin_heading: float = 0.0  # deg from north (clockwise) of the local frame's +x axis
    connect_timeout: float = Field(10.0, gt=0)  # s to open the link and read the TOCs
    arm_timeout: float = Field(2.0, gt=0)  # s for the supervisor to report the vehicle armed
    takeoff_confirm: float = Field(2.0, gt=0)  # s for the supervisor to report flying after takeoff
    log_period_ms: int = Field(50, ge=10, le=2540)  # period of the state log blocks
    control_hz: float = Field(20.0, ge=5.0, le=100.0)  # rate of streamed velocity set-points
    # s a velocity set-point is streamed unrenewed before the high-level commander holds
    velocity_hold: float = Field(0.4, gt=0, lt=WDT_STABILIZE_S)
    climb_speed: float = Field(0.5, gt=0, le=2.0)  # m/s of the take-off trajectory
    land_speed: float = Field(0.3, gt=0, le=1.0)  # m/s of the landing trajectory
    rtl_speed: float = Field(0.5, gt=0, le=2.0)  # m/s of the go_to back to the take-off point
    rtl_tolerance: float = Field(0.15, gt=0)  # m from the take-off point at which RTL lands
    # m^2: arm() refuses while kalman.varPX/PY/PZ is above (estimator not converged)
    max_position_variance: float = Field(0.001, gt=0)
    # s without a packet after which streaming stops and the high-level commander holds
    link_stale_after: float = Field(0.5, gt=0)
    # s of lost link in the air after which the adapter sends landings blindly; 0 = never
    link_loss_land: float = Field(5.0, ge=0)
    cells: int = Field(1, ge=1, le=4)  # battery cells in series (1 on a Crazyflie 2.x)
    # crazyflie-firmware 2026.08 platform_defaults_cf2.h DEFAULT_BAT_LOW_VOLTAGE / _CRITICAL_LOW_VOLTAGE
    # (the persistent params pm.lowVoltage / pm.criticalLowVoltage; 3.35 V low on a CF2.1 brushless)
    # V: arm() refuses at or below it at once (the firmware says lowPower only 5 s later)
    low_voltage: float = Field(3.2, gt=0)
    # V: in the air below it for critical_land_after s the adapter lands where it is
    critical_voltage: float = Field(3.0, gt=0)
    # s below critical_voltage before the landing (a firmware built with CONFIG_PM_AUTO_SHUTDOWN powers
    # off 5 s after it, once in lowPower)
    critical_land_after: float = Field(0.5, ge=0)
    cache_dir: str = ""  # directory for cflib's TOC cache (faster connects); empty = none

    @field_validator("uri")
    @classmethod
    def _uri(cls, value: str) -> str:
        value = value.strip()
        if not value.startswith(_URI_SCHEMES):
            raise ValueError(
                f"must be a cflib URI ({', '.join(s + '...' for s in _URI_SCHEMES)}), got {value!r}"
            )
        return value

    @model_validator(mode="after")
    def _rates(self) -> Params:
        hz, log_ms = self.control_hz, self.log_period_ms
        require_duration(
            "velocity_hold", self.velocity_hold, 2.0 / hz, f"two set-point periods at control_hz {hz:g}"
        )
        require_duration(
            "link_stale_after",
            self.link_stale_after,
            3.0 * log_ms / 1000.0,
            f"three log periods ({log_ms} ms): a healthy link would look stale",
        )
        return self


DEFAULTS: dict[str, Any] = defaults(Params)
