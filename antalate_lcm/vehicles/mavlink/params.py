"""The ``[hlc.autopilot_params]`` of the ``mavlink`` adapter, validated before any I/O.

Closed, strict and finite as every adapter's (`antalate_lcm.vehicles.kit.params`); TOML integers are
accepted where a float is expected (``connect_timeout = 10``).
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator, model_validator

from antalate_lcm.vehicles.kit.params import AdapterParams, defaults, require_duration


class Params(AdapterParams):
    """Every adapter parameter with its default; docs/ardupilot.md has the same table for people."""

    # pymavlink connection string: "tcp:HOST:PORT", "udpin:HOST:PORT", "udpout:HOST:PORT", or a serial
    # device such as "/dev/ttyACM0" (with `baud`)
    connection: str = "tcp:127.0.0.1:5760"
    baud: int = Field(115200, ge=1, le=10_000_000)  # serial baud rate (serial links only)
    source_system: int = Field(245, ge=1, le=255)  # our MAVLink system id (see SYSID_MYGCS)
    source_component: int = Field(191, ge=0, le=255)  # our component id (MAV_COMP_ID_ONBOARD_COMPUTER)
    target_system: int = Field(0, ge=0, le=255)  # the autopilot's system id; 0 = the first heard
    target_component: int = Field(0, ge=0, le=255)  # the autopilot's component id; 0 = AUTOPILOT1
    connect_timeout: float = Field(10.0, gt=0)  # s to open the link and hear the first HEARTBEAT
    ready_timeout: float = Field(30.0, gt=0)  # s arm() waits for STANDBY, EKF position and 3D fix
    ack_timeout: float = Field(1.5, gt=0)  # s per COMMAND_ACK / PARAM_VALUE attempt (two attempts)
    mode_timeout: float = Field(3.0, gt=0)  # s for a HEARTBEAT to confirm a mode change or arming
    stream_rate_hz: float = Field(5.0, gt=0)  # telemetry rate asked of the autopilot
    # resend rate of the current velocity set-point in GUIDED flight; 0 = never resend
    velocity_resend_hz: float = Field(4.0, ge=0)
    # s after the HLC's set_velocity() call beyond which that set-point is never sent again
    setpoint_timeout: float = Field(1.0, gt=0, le=10.0)
    # s without any message from the vehicle after which no set-point is sent (none is queued in a
    # socket buffer during a cut); when the link returns a stop is sent at once
    link_stale_after: float = Field(1.0, gt=0)
    heartbeat_hz: float = Field(1.0, gt=0)  # our GCS HEARTBEAT rate
    # battery cells in series; 0 = learn from BATTERY_STATUS per-cell voltages, else unknown
    cells: int = Field(0, ge=0, le=24)
    check_vehicle: bool = True  # read the vehicle's failsafe parameters on connect
    # write the failsafe parameters the pre-flight check finds wrong (PARAM_SET)
    configure_vehicle: bool = False
    require_vehicle_failsafes: bool = False  # refuse to arm while a failsafe parameter is wrong or unread
    # largest GUID_TIMEOUT (s) the pre-flight check accepts
    max_guid_timeout: float = Field(3.0, gt=0, le=5.0)
    # MAVLink 2 signing: 64 hex digits (the key) or a passphrase (key = SHA-256 of it, as MAVProxy's
    # `signing setup`); empty = no signing
    signing_key: str = ""

    @field_validator("connection")
    @classmethod
    def _connection(cls, value: str) -> str:
        value = value.strip()
        if not value:
            raise ValueError("must be a pymavlink connection string, got an empty string")
        return value

    @model_validator(mode="after")
    def _stale_after_streams(self) -> Params:
        # A healthy link must never look stale: at least two telemetry periods of silence.
        rate = self.stream_rate_hz
        require_duration(
            "link_stale_after",
            self.link_stale_after,
            2.0 / rate,
            f"two telemetry periods at stream_rate_hz {rate:g}: a healthy link would look stale "
            f"(use >= {2.0 / rate:g} s)",
        )
        return self


#: Defaults by name (tools and docs checks).
DEFAULTS: dict[str, Any] = defaults(Params)
