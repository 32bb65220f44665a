"""An operator's client for the station's API, signing commands where the operator is.

The station stores and forwards a signed command field for field; each agent's OSC rebuilds the
LCM message and verifies its MAC with the swarm key before publishing it. So a station (or anyone
who takes it over) can delay or drop a command, never make one up, retarget it or replay it past
the agents' window. The swarm key stays with the operator and the agents.

    with StationClient("https://station:8443", api_key, swarm_key=key, ca_file="ca.pem") as c:
        c.command("TAKEOFF", target="uav1", altitude=15.0)
        c.direction(270.0, 1.5)
        c.agents()

Without a swarm key the commands go unsigned (for swarms that run without one). With one, they are
signed by the code that signs what every node publishes (``core.admission.sealer``), so antalate signs
in one place.
"""

from __future__ import annotations

import math
import ssl
import time
from typing import Any, get_args

import httpx

from antalate_lcm.base.errors import StationClientError as StationClientError
from antalate_lcm.core.admission import sealer
from antalate_lcm.msgs import direction_cmd_t, operator_cmd_t
from antalate_lcm.wire.vocabulary import Command, CommandName

COMMANDS: tuple[CommandName, ...] = get_args(CommandName)


def wrap_azimuth(azimuth: float) -> float:
    """[0, 360): signed commands are not wrapped by the station (it must not touch them)."""
    if not math.isfinite(azimuth):
        raise ValueError(f"azimuth must be a finite number of degrees, got {azimuth!r}")
    wrapped = math.fmod(azimuth, 360.0)
    if wrapped < 0.0:
        wrapped += 360.0
    return 0.0 if wrapped >= 360.0 else wrapped


def _header_fields(msg: Any) -> dict[str, Any]:
    h = msg.header
    return {
        "target": msg.target,
        "utime": h.utime,
        "sender": h.agent,
        "seq": h.seq,
        "mac": bytes(h.mac).hex(),
    }


def build_operator_cmd(
    command: str,
    *,
    target: str = "",
    altitude: float = 0.0,
    sender: str,
    seq: int,
    utime: int,
    key: str | None,
) -> operator_cmd_t:
    """The ``operator_cmd_t`` an operator sends, signed with ``key`` when there is one."""
    if command not in COMMANDS:
        raise ValueError(f"unknown command {command!r}; one of {', '.join(COMMANDS)}")
    if not math.isfinite(altitude) or altitude < 0:
        raise ValueError(f"altitude must be a finite number of metres >= 0, got {altitude!r}")
    msg = operator_cmd_t()
    msg.header.utime, msg.header.agent, msg.header.seq = utime, sender, seq
    msg.command = Command[command].value
    msg.target = target
    msg.altitude = float(altitude)
    if key:
        sealer(key)(msg)  # fills header.mac: the nodes' own signing code (core/admission.py)
    return msg


def build_direction_cmd(
    azimuth: float,
    speed: float,
    *,
    active: bool = True,
    target: str = "",
    sender: str,
    seq: int,
    utime: int,
    key: str | None,
) -> direction_cmd_t:
    """The ``direction_cmd_t`` an operator sends, signed with ``key`` when there is one."""
    if not math.isfinite(speed) or speed < 0:
        raise ValueError(f"speed must be a finite number of m/s >= 0, got {speed!r}")
    msg = direction_cmd_t()
    msg.header.utime, msg.header.agent, msg.header.seq = utime, sender, seq
    msg.active, msg.azimuth, msg.speed, msg.target = active, wrap_azimuth(azimuth), float(speed), target
    if key:
        sealer(key)(msg)  # fills header.mac: the nodes' own signing code (core/admission.py)
    return msg


def operator_cmd_wire(msg: operator_cmd_t) -> dict[str, Any]:
    """The ``operator_cmd`` object of ``POST /api/commands`` for a signed message."""
    return {**_header_fields(msg), "command": Command(msg.command).name, "altitude": msg.altitude}


def direction_cmd_wire(msg: direction_cmd_t) -> dict[str, Any]:
    """The ``direction_cmd`` object of ``POST /api/commands`` for a signed message."""
    return {**_header_fields(msg), "active": msg.active, "azimuth": msg.azimuth, "speed": msg.speed}


class StationClient:
    """``GET /api/agents`` and ``POST /api/commands`` with an API key; commands signed with the
    swarm key when one is given. ``sender`` is the operator's name in the header (the MC logs it
    and keys duplicates on it)."""

    def __init__(
        self,
        url: str,
        api_key: str,
        *,
        swarm_key: str | None = None,
        sender: str = "station-client",
        ca_file: str | None = None,
        timeout: float = 5.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        self.url = url.rstrip("/")
        self.swarm_key = swarm_key or None
        self.sender = sender
        self._seq = 0
        verify: Any = ssl.create_default_context(cafile=ca_file) if ca_file else True
        self._http = httpx.Client(
            base_url=self.url,
            timeout=timeout,
            verify=verify,
            transport=transport,
            headers={"Authorization": f"Bearer {api_key}"},
        )

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> StationClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def next_seq(self) -> int:
        """Milliseconds on a 2^31 wheel, never going back within a client: another run of the CLI a
        moment later does not reuse a seq the MCs still remember as a duplicate (60 s)."""
        self._seq = max(self._seq + 1, time.time_ns() // 1_000_000 % (2**31 - 2) + 1)
        return self._seq

    def _post(self, body: dict[str, Any]) -> dict[str, Any]:
        r = self._http.post("/api/commands", json=body)
        return dict(self._json(r))

    @staticmethod
    def _json(r: httpx.Response) -> Any:
        if r.status_code != 200:
            try:
                detail = str(r.json().get("detail", r.text))
            except ValueError:
                detail = r.text[:200]
            raise StationClientError(r.status_code, detail)
        return r.json()

    def agents(self) -> list[dict[str, Any]]:
        return list(self._json(self._http.get("/api/agents")))

    def command(self, command: str, *, target: str | None = None, altitude: float = 0.0) -> dict[str, Any]:
        """Queue TAKEOFF, LAND or RTL for ``target`` (a name; None = every agent)."""
        if self.swarm_key is None:
            body: dict[str, Any] = {"command": command}
            if target:
                body["target"] = target
            if altitude:
                body["altitude"] = altitude
            build_operator_cmd(
                command, altitude=altitude, sender=self.sender, seq=1, utime=1, key=None
            )  # checks
            return self._post(body)
        msg = build_operator_cmd(
            command,
            target=target or "",
            altitude=altitude,
            sender=self.sender,
            seq=self.next_seq(),
            utime=time.time_ns() // 1000,
            key=self.swarm_key,
        )
        return self._post({"operator_cmd": operator_cmd_wire(msg)})

    def direction(
        self, azimuth: float, speed: float, *, active: bool = True, target: str | None = None
    ) -> dict[str, Any]:
        """Queue a direction for ``target`` (a name; None = every agent)."""
        msg = build_direction_cmd(
            azimuth,
            speed,
            active=active,
            target=target or "",
            sender=self.sender,
            seq=self.next_seq(),
            utime=time.time_ns() // 1000,
            key=self.swarm_key,
        )
        if self.swarm_key is None:
            body: dict[str, Any] = {
                "direction": {"azimuth": msg.azimuth, "speed": msg.speed, "active": active}
            }
            if target:
                body["target"] = target
            return self._post(body)
        return self._post({"direction_cmd": direction_cmd_wire(msg)})
