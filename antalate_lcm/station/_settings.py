"""Station parameters and where its database lives by default."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from ._auth import Role

MEMORY = ":memory:"
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080


def given_settings(source: object, names: Iterable[tuple[str, str]]) -> dict[str, Any]:
    """``{setting: value}`` for each ``(attribute, setting)`` of ``names`` that ``source`` sets (not None):
    what the station file and then the command line each lay over the defaults."""
    return {
        setting: value for attribute, setting in names if (value := getattr(source, attribute)) is not None
    }


def default_db_path() -> Path:
    """``$XDG_DATA_HOME/antalate/station.sqlite``, else ``~/.local/share/antalate/station.sqlite``.

    A fixed per-user location means ``antalate station`` with no arguments keeps its agents and
    tokens across restarts, which is what a person expects of a server that hands out tokens.
    """
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "antalate" / "station.sqlite"


class ApiKey(BaseModel):
    """One operator credential as the config holds it: a name, a role and SHA-256 of the key."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(min_length=1, max_length=64, description="who holds the key (for the log)")
    role: Role
    sha256: str = Field(description="hex SHA-256 of the key (antalate station-key api prints it)")

    @field_validator("sha256")
    @classmethod
    def _hex(cls, value: str) -> str:
        if not re.fullmatch(r"[0-9a-fA-F]{64}", value):
            raise ValueError("64 hex digits (the SHA-256 of the key, not the key itself)")
        return value.lower()


class RateLimits(BaseModel):
    """Per source address and per agent; None turns a limit off (benchmarks, trusted test rigs)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    registrations_per_minute: float | None = Field(
        60.0, gt=0.0, description="first-contact reports per source address, sustained"
    )
    registration_burst: int = Field(60, ge=1, description="first-contact reports per source address at once")
    reports_per_second: float | None = Field(20.0, gt=0.0, description="reports per agent, sustained")
    report_burst: int = Field(40, ge=1, description="reports per agent at once")
    address_reports_per_second: float | None = Field(
        2000.0, gt=0.0, description="requests of any kind per source address, sustained"
    )
    address_burst: int = Field(4000, ge=1)


class StationSettings(BaseModel):
    """Everything that changes what the station answers or keeps. Immutable once the app is built."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    db_path: str = Field(
        default_factory=lambda: str(default_db_path()),
        description='SQLite file (created with its directory if missing), or ":memory:"',
    )
    range_m: float = Field(100.0, gt=0.0, description="sensing range of the simulated front sector, metres")
    fov_deg: float = Field(
        60.0, gt=0.0, le=360.0, description="full field of view of the front sector, degrees"
    )
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
        24 * 3600.0,
        gt=0.0,
        description="delete history rows older than this (a row is ~200 bytes); None = keep everything",
    )
    max_body_bytes: int = Field(1 << 20, ge=1024, description="larger requests get 413")
    api_keys: tuple[ApiKey, ...] = Field(
        (), description="operator credentials; none = the operator endpoints answer 401 to everyone"
    )
    registration_key: str | None = Field(
        None,
        description="hex key derived from the swarm key; set = registration needs proof of the swarm key",
    )
    registration_window_s: float = Field(
        60.0, gt=0.0, description="accepted clock difference of a registration proof, seconds"
    )
    rate_limits: RateLimits = Field(default_factory=RateLimits)

    @field_validator("registration_key")
    @classmethod
    def _reg_hex(cls, value: str | None) -> str | None:
        if value is not None and not re.fullmatch(r"[0-9a-fA-F]{64}", value):
            raise ValueError("64 hex digits (antalate station-key registration prints it)")
        return value.lower() if value is not None else None

    @field_validator("db_path", mode="before")
    @classmethod
    def _path_to_str(cls, value: object) -> object:
        return os.fspath(value) if isinstance(value, os.PathLike) else value
