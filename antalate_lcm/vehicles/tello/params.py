"""The Tello adapter's parameters (``[hlc.autopilot_params]`` with ``autopilot = "tello"``).

One pydantic model, closed, strict and finite as every adapter's (`antalate_lcm.vehicles.kit.params`),
validated in the adapter's constructor: a typo or a wrong type fails there with a `ValueError` naming
the key, instead of flying on a default. Every key is documented in
docs/tello.md and set in examples/tello.toml.
"""

from __future__ import annotations

import ipaddress
import logging
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from antalate_lcm.vehicles.kit.params import AdapterParams, defaults

#: The Tello lands itself this long after the last command it received (SDK 3.0 user guide, "Safety
#: Function"): counted from the end of the last command it executed.
TELLO_AUTOLAND_S = 15.0


class Params(AdapterParams):
    """Every parameter with its default; ``strict``: ``"1.0"`` is not a number, ``true`` is not 1."""

    host: str = "192.168.10.1"  # the Tello's IP (192.168.10.1 in its own access-point mode)
    home_lat: float = Field(default=32.7767, ge=-90.0, le=90.0)  # deg: power-on point
    home_lon: float = Field(default=35.0231)  # deg
    home_heading: float = Field(default=0.0)  # deg from north the Tello faced at power-on
    max_speed: float = Field(default=1.0, gt=0)  # m/s horizontally at rc 100
    max_vertical_speed: float = Field(default=1.0, gt=0)  # m/s at rc 100
    max_yaw_rate: float = Field(default=100.0, gt=0)  # deg/s at rc 100
    control_hz: float = Field(default=20.0, gt=0, le=50.0)  # rc rate
    keepalive_s: float = Field(default=5.0, gt=0)  # s between keepalives in the air
    velocity_hold: float = Field(default=1.0, gt=0)  # s a set-point is streamed unrenewed
    rtl_speed: float = Field(default=0.5, gt=0)  # m/s back to the take-off point
    rtl_tolerance: float = Field(default=0.3, gt=0)  # m from it at which the RTL lands
    vgx_sign: Literal[1, -1] = 1  # sign of the state's vgx (forward along yaw 0 is positive)
    vgy_sign: Literal[1, -1] = 1  # sign of the state's vgy (right of yaw 0 is positive)
    velocity_frame: Literal["ground", "body"] = "ground"  # frame of vgx/vgy
    altitude_source: Literal["h", "tof"] = "h"  # the state's height, or the downward range finder
    takeoff_altitude_mode: Literal["rc", "up"] = "rc"  # climb with rc after takeoff, or blocking up/down
    min_battery: float = Field(default=10.0, ge=0, le=100)  # percent: arm() refuses at/below
    command_timeout: float = Field(default=7.0, gt=0)  # s for an answer (command, battery?)
    takeoff_timeout: float = Field(default=20.0, gt=0)  # s for takeoff/land/up to finish
    velocity_unit_check: bool = True  # check vgx/vgy/vgz are dm/s against the height; RTL refused if not
    command_spacing: float = Field(
        default=0.15, ge=0.1, le=1.0
    )  # s between commands (not rc) and after an answer: a Tello ignores closer ones
    retry_count: int = Field(default=3, ge=1)  # attempts of `command` at connect
    state_timeout: float = Field(default=2.0, gt=0)  # s connect() waits for state
    link_loss_timeout: float = Field(default=2.0, gt=0)  # s without state: stop commanding
    autoland_s: float = Field(default=TELLO_AUTOLAND_S, gt=0)  # the Tello's own auto-landing
    link_back_hover: float = Field(default=10.0, gt=0)  # s hovering uncommanded after a loss
    djitellopy_log_level: str = "WARNING"  # djitellopy logs every command (and rc) at INFO

    @field_validator("host")
    @classmethod
    def _ipv4(cls, value: str) -> str:
        try:
            ipaddress.IPv4Address(value)
        except ValueError:
            raise ValueError(
                "must be an IPv4 address (djitellopy matches replies to drones by the sender's IP)"
            ) from None
        return value

    @field_validator("vgx_sign", "vgy_sign", mode="before")
    @classmethod
    def _not_bool(cls, value: Any) -> Any:
        if isinstance(value, bool):
            raise ValueError("must be 1 or -1, not a boolean")
        return value

    @field_validator("djitellopy_log_level")
    @classmethod
    def _level(cls, value: str) -> str:
        if not isinstance(logging.getLevelName(value.upper()), int):
            raise ValueError("must be a logging level name (DEBUG, INFO, WARNING, ERROR)")
        return value.upper()

    @model_validator(mode="after")
    def _rates(self) -> Params:
        if self.keepalive_s >= self.autoland_s:
            raise ValueError(
                f"keepalive_s must be < autoland_s {self.autoland_s:g} (the Tello lands that long "
                f"after the last command), got {self.keepalive_s!r}"
            )
        if self.keepalive_s < 1.0 / self.control_hz:
            raise ValueError(
                f"keepalive_s {self.keepalive_s:g} is shorter than one control tick "
                f"(control_hz {self.control_hz:g})"
            )
        return self


#: Parameters and their defaults, for docs and tests.
DEFAULTS: dict[str, Any] = defaults(Params)
