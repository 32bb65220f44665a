"""Between LCM messages and the station's JSON (pure: no I/O), using the station's own wire models.

A command the operator signed comes back as the very message the operator built (header, MAC and
all), so the agent can verify it; one the station made itself has no MAC and gets the OSC's header.
"""

from __future__ import annotations

import base64
import json
import secrets
import time
from typing import Any

from pydantic import ValidationError

from antalate_lcm.base.errors import ReplyError as ReplyError
from antalate_lcm.msgs import direction_cmd_t, hlc_state_t, mc_state_t, operator_cmd_t, payload_t, telemetry_t
from antalate_lcm.station import models, registration_key, registration_mac
from antalate_lcm.wire.vocabulary import Command, HlcState, McState, name_of

_TELEMETRY_FIELDS = ("lat", "lon", "alt", "heading", "vn", "ve", "vd", "battery", "armed", "in_air", "mode")


def registration(
    agent: str, swarm_key: str, *, utime: int | None = None, nonce: str | None = None
) -> dict[str, Any]:
    """The proof of the swarm key a first report carries: a MAC with the derived registration key."""
    utime = time.time_ns() // 1000 if utime is None else utime
    nonce = secrets.token_urlsafe(18) if nonce is None else nonce
    return {
        "utime": utime,
        "nonce": nonce,
        "mac": registration_mac(registration_key(swarm_key), agent, utime, nonce),
    }


def report_body(
    token: str | None,
    mc: mc_state_t | None,
    hlc: hlc_state_t | None,
    telemetry: telemetry_t | None,
    feedback: payload_t | None,
    *,
    agent: str | None = None,
    swarm_key: str = "",
) -> dict[str, Any]:
    """The report; without a token it registers ``agent``, with a proof when there is a swarm key."""
    body: dict[str, Any] = {
        "token": token,
        "agent": agent,
        "mc_state": name_of(McState, mc.state) if mc is not None else None,
        "hlc_state": name_of(HlcState, hlc.state) if hlc is not None else None,
        "telemetry": None,
        "feedback": None,
    }
    if telemetry is not None and telemetry.lat == telemetry.lat and telemetry.lon == telemetry.lon:
        t = {k: getattr(telemetry, k) for k in _TELEMETRY_FIELDS}
        t = {k: (v if not isinstance(v, float) or v == v else None) for k, v in t.items()}
        body["telemetry"] = {k: v for k, v in t.items() if v is not None} | {"agent": telemetry.header.agent}
    if token is None and agent is not None and swarm_key:
        body["registration"] = registration(agent, swarm_key)
    if feedback is not None:
        data = bytes(feedback.data)
        try:
            body["feedback"] = {
                "content_type": feedback.content_type or "application/octet-stream",
                "data": data.decode("utf-8"),
                "encoding": "utf-8",
            }
        except UnicodeDecodeError:
            body["feedback"] = {
                "content_type": feedback.content_type or "application/octet-stream",
                "data": base64.b64encode(data).decode("ascii"),
                "encoding": "base64",
            }
    return body


def parse_reply(raw: bytes) -> models.ReportReply:
    """Validate a reply completely before anything in it is acted on."""
    try:
        doc = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReplyError(f"not JSON: {exc}") from None
    try:
        return models.ReportReply.model_validate(doc)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "reply"
        raise ReplyError(f"{where}: {first['msg']}") from None


def _signed_header(msg: Any, c: models.OperatorCommand | models.DirectionCommand, agent: str) -> None:
    """The operator's header as signed, or for a station-made command only the target (this agent)."""
    if c.mac is None:
        msg.target = agent
        return
    assert c.target is not None and c.utime is not None and c.sender is not None  # _Signature: all or none
    msg.target = c.target
    msg.header.utime, msg.header.agent, msg.header.seq = c.utime, c.sender, c.seq
    mac = bytes.fromhex(c.mac)
    msg.header.mac_len, msg.header.mac = len(mac), mac


def operator_cmd(reply: models.ReportReply, agent: str) -> operator_cmd_t | None:
    c = reply.operator_cmd
    if c is None:
        return None
    msg = operator_cmd_t()
    msg.command = Command[c.command].value
    msg.altitude = float(c.altitude or 0.0)
    _signed_header(msg, c, agent)
    return msg


def direction_cmd(reply: models.ReportReply, agent: str) -> direction_cmd_t | None:
    d = reply.direction_cmd
    if d is None:
        return None
    msg = direction_cmd_t()
    msg.active, msg.azimuth, msg.speed = d.active, d.azimuth, d.speed
    _signed_header(msg, d, agent)
    return msg


def payload(reply: models.ReportReply) -> payload_t | None:
    p = reply.payload
    if p is None:
        return None
    try:
        data = p.content()
    except ValueError as exc:
        raise ReplyError(f"payload.data: {exc}") from None
    msg = payload_t()
    msg.content_type = p.content_type
    msg.data = data
    msg.size = len(data)
    return msg
