"""Station parameters and where its database lives by default."""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

MEMORY = ":memory:"
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080


def default_db_path() -> Path:
    """``$XDG_DATA_HOME/antalate/station.sqlite``, else ``~/.local/share/antalate/station.sqlite``.

    A fixed per-user location means ``antalate station`` with no arguments keeps its agents and
    tokens across restarts, which is what a person expects of a server that hands out tokens.
    """
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "antalate" / "station.sqlite"


class StationSettings(BaseModel):
    """Everything that changes what the station answers or keeps. Immutable once the app is built."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    db_path: str = Field(
        default_factory=lambda: str(default_db_path()),
        description='SQLite file (created with its directory if missing), or ":memory:"',
    )
    range_m: float = Field(100.0, gt=0.0, description="sensing range of the simulated front sector, metres")
    fov_deg: float = Field(60.0, gt=0.0, le=360.0, description="full field of view of the front sector, degrees")
    stale_after_s: float = Field(
        5.0, gt=0.0, description="an agent with no report for this long is not detected by others"
    )
    command_ttl_s: float | None = Field(
        60.0, gt=0.0, description="a queued command older than this is dropped, not delivered; None = never"
    )
    history: bool = Field(True, description="append every report to the reports table")
    history_flush_s: float = Field(
        0.5, gt=0.0, le=60.0, description="reports are written in one transaction per this interval"
    )
    history_retention_s: float | None = Field(
        24 * 3600.0, gt=0.0,
        description="delete history rows older than this (a row is ~200 bytes); None = keep everything",
    )
    max_body_bytes: int = Field(1 << 20, ge=1024, description="larger requests get 413")

    @field_validator("db_path", mode="before")
    @classmethod
    def _path_to_str(cls, value: object) -> object:
        return os.fspath(value) if isinstance(value, os.PathLike) else value
