"""The reference operator station (``antalate station``): HTTP + SQLite + geodesic sector sensing.

Public API (everything else in this package is private):

* `create_app` — the FastAPI app, for embedding in another ASGI server;
* `StationSettings`, `default_db_path` — parameters and the default database location;
* `run_station` — serve until interrupted (the CLI's entry);
* `StationServer` — the station in a background thread (tests, demos, benchmarks);
* `models` — the wire format as pydantic models, for clients such as the OSC.

The protocol is described in ``docs/station-protocol.md``.
"""

from __future__ import annotations

from . import _models as models
from ._app import create_app
from ._server import StationServer, run_station
from ._settings import DEFAULT_HOST, DEFAULT_PORT, StationSettings, default_db_path

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "StationServer",
    "StationSettings",
    "create_app",
    "default_db_path",
    "models",
    "run_station",
]
