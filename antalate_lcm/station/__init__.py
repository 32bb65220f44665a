"""The reference operator station (``antalate station``): HTTP + SQLite + geodesic sector sensing.

Public API (the underscored modules are private):

* `create_app` — the FastAPI app, for embedding in another ASGI server;
* `StationSettings`, `default_db_path`, `DEFAULT_HOST`, `DEFAULT_PORT` — parameters and defaults;
* `run_station` — serve until interrupted (what ``antalate station`` calls);
* `load_station_file`, `StationFile`, `ApiKey`, `RateLimits` — the station file (``[station]``, API keys,
  rate limits), which the web console reads for its keys and the demo writes;
* `registration_key`, `registration_mac` — how an OSC proves at registration that it holds the swarm
  key; `new_api_key`, `sha256_hex` — an operator API key and the digest the station stores of it;
* `StationServer` — the station in a background thread (tests, demos, benchmarks);
* the wire models (`ReportRequest`, `ReportReply`, `Telemetry`, `Feedback`, `Payload`,
  `OperatorCommand`, `DirectionCommand`, `PeerDetection`, `CommandRequest`, …), also as the
  namespace `models`, for clients such as the OSC;
* `sector` — the pure front-sector geometry;
* ``antalate_lcm.station.client`` — `StationClient`, an operator's API client that signs commands
  with the swarm key where the operator is (import it directly; it is not loaded here).

The server half (FastAPI, uvicorn) is imported on first use, so a client that only needs the wire
models does not pay for it. The protocol is described in ``docs/station-protocol.md`` and
``docs/openapi.json``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from . import _models as models
from . import sector
from ._auth import new_api_key, registration_key, registration_mac, sha256_hex
from ._models import (
    AgentInfo,
    CommandRequest,
    CommandResponse,
    Direction,
    DirectionCommand,
    ErrorResponse,
    Feedback,
    OperatorCommand,
    Payload,
    PeerDetection,
    QueuedCommand,
    ReportReply,
    ReportRequest,
    Telemetry,
)
from ._settings import DEFAULT_HOST, DEFAULT_PORT, ApiKey, RateLimits, StationSettings, default_db_path

if TYPE_CHECKING:
    from ._app import create_app
    from ._file import StationFile, load_station_file
    from ._server import StationServer, run_station

_LAZY = {
    "create_app": "._app",
    "run_station": "._server",
    "StationServer": "._server",
    "load_station_file": "._file",
    "StationFile": "._file",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "AgentInfo",
    "ApiKey",
    "CommandRequest",
    "CommandResponse",
    "Direction",
    "DirectionCommand",
    "ErrorResponse",
    "Feedback",
    "OperatorCommand",
    "Payload",
    "PeerDetection",
    "QueuedCommand",
    "RateLimits",
    "ReportReply",
    "ReportRequest",
    "StationFile",
    "StationServer",
    "StationSettings",
    "Telemetry",
    "create_app",
    "default_db_path",
    "load_station_file",
    "models",
    "new_api_key",
    "registration_key",
    "registration_mac",
    "run_station",
    "sector",
    "sha256_hex",
]
