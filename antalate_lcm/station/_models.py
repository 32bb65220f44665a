"""The station's JSON wire format (docs/design.md §9), as pydantic models.

These models are the protocol: the station validates every request with them, the OSC can import
them to build its reports and to read replies, and FastAPI turns them into the OpenAPI document
(``docs/openapi.json``). ``docs/station-protocol.md`` explains the semantics in prose.

Validation is strict on purpose. A station that silently turned ``"12"`` into ``12.0`` or
``NaN`` into a position would hide a broken client until an aircraft is placed at the wrong spot;
a 422 with the offending field tells the author of the client at once. Unknown *fields* are
ignored, though, so an OSC built against a newer protocol revision still talks to an older station.
"""

from __future__ import annotations

import base64
import binascii
import math
import re
from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from antalate_lcm.wire.vocabulary import CommandName, HlcStateName, McStateName

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self is 3.11+

#: An agent name as the config allows it (it is part of LCM channel names).
AGENT_NAME = r"^[A-Za-z0-9_.-]{1,64}$"
_HEX64 = r"^[0-9a-fA-F]{64}$"
_INT32_MAX = 2**31 - 1
_INT64_MAX = 2**63 - 1
MAX_ALTITUDE = (
    1000.0  # m, as antalate_lcm.wire.validation.MAX_TAKEOFF_ALTITUDE: above it is a typo or an attack
)
MAX_SPEED = 100.0


class _Wire(BaseModel):
    """Common config: strict types, no NaN/inf, unknown fields ignored (forward compatibility)."""

    model_config = ConfigDict(strict=True, allow_inf_nan=False, extra="ignore", frozen=True)


def _wrap_360(angle: float) -> float:
    """Headings/azimuths are accepted in any turn (e.g. -10 or 370) and stored in [0, 360)."""
    wrapped = math.fmod(angle, 360.0)
    if wrapped < 0.0:
        wrapped += 360.0
    return 0.0 if wrapped >= 360.0 else wrapped


class Telemetry(_Wire):
    """``telemetry_t`` without its header, keyed by the field names; ``agent`` is the header's name.

    Only the position and heading are required (the sector test needs them); the rest default to the
    values ``telemetry_t`` uses for "unknown", so a minimal script can report with three numbers.
    """

    lat: float = Field(ge=-90.0, le=90.0, description="degrees, WGS84")
    lon: float = Field(ge=-180.0, le=180.0, description="degrees, WGS84")
    alt: float = Field(0.0, description="metres above the home point (not used by the sector test)")
    heading: float = Field(description="degrees from true north, clockwise; any value, wrapped to [0, 360)")
    vn: float = Field(0.0, description="m/s, north")
    ve: float = Field(0.0, description="m/s, east")
    vd: float = Field(0.0, description="m/s, down")
    battery: float = Field(-1.0, description="percent; -1 = unknown")
    armed: bool = False
    in_air: bool = False
    mode: str = Field("", max_length=64, description="the autopilot's own mode name")
    agent: str | None = Field(
        None, max_length=128, description="agent name from the message header (may be an anonymous token)"
    )

    @field_validator("heading")
    @classmethod
    def _heading_in_one_turn(cls, value: float) -> float:
        return _wrap_360(value)


class _EncodedData(_Wire):
    """What Feedback and Payload share: ``data`` is text as ``encoding`` says, checked to decode (base64,
    RFC 4648) so a client bug shows at its source, and handed on as the bytes LCM carries. The fields are
    each model's own (for their order and descriptions in the OpenAPI document); this names them for
    the type checker only."""

    if TYPE_CHECKING:
        data: str
        encoding: Literal["utf-8", "base64"]

    @model_validator(mode="after")
    def _base64_decodes(self) -> Self:
        if self.encoding == "base64":
            try:
                base64.b64decode(self.data, validate=True)
            except (binascii.Error, ValueError) as exc:
                raise ValueError(f"data is not valid base64: {exc}") from None
        return self

    def content(self) -> bytes:
        """The payload bytes, whatever the encoding: what an LCM ``payload_t.data`` holds."""
        return base64.b64decode(self.data) if self.encoding == "base64" else self.data.encode("utf-8")


class Feedback(_EncodedData):
    """Agent → station payload (``payload_t`` on ``{agent}/OPERATOR_FEEDBACK``), stored with the report.

    ``data`` is text. Binary content travels base64-encoded with ``encoding: "base64"``; the station
    checks that it decodes, so a client bug shows up at the source rather than in a later reader.
    """

    content_type: str = Field(min_length=1, max_length=255, description='MIME type, e.g. "image/jpeg"')
    data: str
    encoding: Literal["utf-8", "base64"] = Field(
        "utf-8",
        description='"utf-8": data is the content itself; "base64": data is base64 (RFC 4648) of the bytes',
    )


class Payload(_EncodedData):
    """Station → agent payload (``payload_t`` on ``{agent}/OPERATOR_PAYLOAD``); same shape as feedback."""

    content_type: str = Field(
        min_length=1, max_length=255, description='MIME type; the reference station sends "application/json"'
    )
    data: str
    encoding: Literal["utf-8", "base64"] = "utf-8"


class PeerDetection(_Wire):
    """The reference station's payload JSON: the fields of ``peer_detection_t`` (without header)."""

    detected: bool
    count: int = Field(ge=0, description="peers inside the front sector")
    nearest_range: float = Field(ge=0.0, description="metres to the nearest of them; 0 when none")
    nearest_bearing: float = Field(
        description="degrees relative to the reporter's heading, clockwise positive, in (-180, 180]; 0 when none"
    )


class Registration(_Wire):
    """Proof that a registering agent holds the swarm key: a MAC with the registration key
    (derived from the swarm key) over the name, the time and a nonce; see docs/station-protocol.md."""

    utime: int = Field(ge=0, le=_INT64_MAX, description="agent clock, microseconds since the epoch")
    nonce: str = Field(pattern=r"^[A-Za-z0-9_-]{16,64}$", description="random, never reused")
    mac: str = Field(pattern=_HEX64, description="hex HMAC-SHA256(registration key, message)")


class ReportRequest(_Wire):
    """What the OSC POSTs to ``/api/report`` every ``1/rate`` seconds.

    Everything but the token may be null: an OSC that has not heard the MC, the HLC or any telemetry
    yet still reports, to get its token and any queued commands.
    """

    token: str | None = Field(None, max_length=128, description="null/absent on first contact (registration)")
    agent: str | None = Field(
        None,
        pattern=AGENT_NAME,
        description="the agent's name; at registration it claims the name (else telemetry.agent does)",
    )
    registration: Registration | None = Field(
        None,
        description="proof of the swarm key, needed at registration when the station has a registration key",
    )
    mc_state: McStateName | None = None
    hlc_state: HlcStateName | None = None
    telemetry: Telemetry | None = None
    feedback: Feedback | None = None


class _Signature(_Wire):
    """The header of an operator-signed LCM command, forwarded untouched so the agent can verify it.

    All four are absent for a command the station made itself (unsigned).
    """

    target: str | None = Field(None, max_length=64, description='the signed target: "" = every agent')
    utime: int | None = Field(None, ge=0, le=_INT64_MAX, description="header.utime set by the operator, µs")
    sender: str | None = Field(None, max_length=64, description="header.agent: the operator's name")
    mac: str | None = Field(
        None, pattern=_HEX64, description="header.mac (hex): HMAC-SHA256 with the swarm key"
    )

    @model_validator(mode="after")
    def _all_or_none(self) -> _Signature:
        parts = (self.target, self.utime, self.sender, self.mac)
        if any(p is not None for p in parts) and any(p is None for p in parts):
            raise ValueError("a signed command carries all of target, utime, sender and mac")
        return self

    @property
    def signed(self) -> bool:
        return self.mac is not None


class OperatorCommand(_Signature):
    """One queued ``operator_cmd_t``; ``seq`` goes into its header so the MC can acknowledge it."""

    command: CommandName
    altitude: float | None = Field(
        None, ge=0.0, le=MAX_ALTITUDE, description="takeoff altitude in m; absent or 0 = the agent's default"
    )
    seq: int = Field(ge=1, le=_INT32_MAX)


class DirectionCommand(_Signature):
    """One queued ``direction_cmd_t``."""

    active: bool
    azimuth: float = Field(ge=0.0, lt=360.0, description="degrees from true north, [0, 360)")
    speed: float = Field(ge=0.0, le=MAX_SPEED, description="m/s")
    seq: int = Field(ge=1, le=_INT32_MAX)


class ReportReply(_Wire):
    """The station's answer to a report. Absent optional fields mean "nothing for you"."""

    token: str = Field(description="keep it and send it with every later report")
    operator_cmd: OperatorCommand | None = None
    direction_cmd: DirectionCommand | None = None
    payload: Payload | None = None


class Direction(_Wire):
    """The ``direction`` part of a command request."""

    azimuth: float = Field(description="degrees from true north; any value, wrapped to [0, 360)")
    speed: float = Field(ge=0.0, le=100.0, description="m/s")
    active: bool = True

    @field_validator("azimuth")
    @classmethod
    def _azimuth_in_one_turn(cls, value: float) -> float:
        return _wrap_360(value)


class _SignedHeader(_Wire):
    target: str = Field(
        max_length=64, description='the command\'s target field as signed: an agent name, "" = every agent'
    )
    utime: int = Field(gt=0, le=_INT64_MAX, description="header.utime, µs since the epoch (operator clock)")
    sender: str = Field(min_length=1, max_length=64, description="header.agent: the operator's name")
    seq: int = Field(ge=1, le=_INT32_MAX, description="header.seq: the MC acknowledges it")
    mac: str = Field(pattern=_HEX64, description="header.mac, hex: HMAC-SHA256 over the encoded message")

    @field_validator("target")
    @classmethod
    def _name_or_empty(cls, value: str) -> str:
        if value and not re.fullmatch(AGENT_NAME, value):
            raise ValueError("an agent name (letters, digits, '-', '_', '.') or \"\" for every agent")
        return value


class SignedOperatorCommand(_SignedHeader):
    """An ``operator_cmd_t`` signed by the operator (``antalate_lcm.wire.security.sign``), field by field."""

    command: CommandName
    altitude: float = Field(0.0, ge=0.0, le=MAX_ALTITUDE, description="m; 0 = the agent's default")


class SignedDirectionCommand(_SignedHeader):
    """A ``direction_cmd_t`` signed by the operator, field by field."""

    active: bool = True
    azimuth: float = Field(
        ge=0.0, lt=360.0, description="degrees from true north, [0, 360): not wrapped once signed"
    )
    speed: float = Field(ge=0.0, le=MAX_SPEED, description="m/s")


class CommandRequest(_Wire):
    """``POST /api/commands``: exactly one of ``command``, ``direction``, ``operator_cmd`` and
    ``direction_cmd``. The last two are signed by the operator and forwarded exactly; their own
    ``target`` decides who gets them. The first two are unsigned: ``target`` absent = every agent."""

    command: CommandName | None = None
    altitude: float | None = Field(None, gt=0.0, le=MAX_ALTITUDE, description="only with TAKEOFF")
    direction: Direction | None = None
    operator_cmd: SignedOperatorCommand | None = None
    direction_cmd: SignedDirectionCommand | None = None
    target: str | None = Field(
        None, min_length=1, max_length=128, description="an agent's id or name; absent = every known agent"
    )

    @model_validator(mode="after")
    def _exactly_one(self) -> CommandRequest:
        given = [
            x for x in (self.command, self.direction, self.operator_cmd, self.direction_cmd) if x is not None
        ]
        if len(given) != 1:
            raise ValueError('give exactly one of "command", "direction", "operator_cmd" and "direction_cmd"')
        if self.altitude is not None and self.command != "TAKEOFF":
            raise ValueError('"altitude" only goes with "command": "TAKEOFF"')
        if self.target is not None and self.signed:
            raise ValueError('a signed command carries its own target: leave "target" out')
        return self

    @property
    def signed(self) -> bool:
        return self.operator_cmd is not None or self.direction_cmd is not None


class QueuedCommand(BaseModel):
    """One delivery the station queued: which agent will get which command."""

    id: str = Field(description="the agent's public id")
    name: str
    seq: int
    operator_cmd: OperatorCommand | None = None
    direction_cmd: DirectionCommand | None = None


class CommandResponse(BaseModel):
    """What ``POST /api/commands`` queued: one entry per agent (empty when no agent is known yet)."""

    seq: int = Field(description="the command's sequence number, the same for every agent it was queued for")
    target: str | None
    queued: list[QueuedCommand]


class AgentInfo(BaseModel):
    """One agent as ``GET /api/agents`` lists it (never with its token: tokens are secrets)."""

    id: str = Field(description="public id: a command may target it; not a credential")
    name: str
    first_seen: float = Field(description="UNIX time (s) of the first report")
    last_seen: float | None = Field(description="UNIX time (s) of the latest report")
    stale: bool = Field(description="no report for longer than the station's stale_after_s")
    mc_state: str | None
    hlc_state: str | None
    telemetry: Telemetry | None
    pending_commands: int


class ErrorResponse(BaseModel):
    """Every 4xx the station sends: a sentence for a person and, for invalid input, where it is wrong."""

    detail: str
    errors: list[dict[str, object]] = Field(default_factory=list)
