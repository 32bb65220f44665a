"""The station's TOML config file (``antalate station --config station.toml``).

Secrets are never in it in the clear: API keys appear as SHA-256, the registration key is derived
from the swarm key and cannot sign commands. A bad file stops the station before it listens, with
the file, the key and what was expected (like the agents' config).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from antalate_lcm.base.errors import ConfigError
from antalate_lcm.base.strict import dotted
from antalate_lcm.core.config import read_toml_file

from ._settings import DEFAULT_HOST, DEFAULT_PORT, ApiKey, RateLimits, StationSettings, given_settings


class _StationTable(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = DEFAULT_HOST
    port: int = Field(DEFAULT_PORT, ge=0, le=65535)
    db: str | None = None
    range: float | None = None
    fov: float | None = None
    stale_after: float | None = None
    command_ttl: float | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    registration_key: str | None = None


class _StationFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    station: _StationTable = Field(default_factory=_StationTable)
    rate_limits: RateLimits = Field(default_factory=RateLimits)
    api_keys: list[ApiKey] = Field(default_factory=list)


@dataclass(frozen=True)
class StationFile:
    """What ``antalate station`` needs from the file: the settings and where to listen."""

    settings: StationSettings
    host: str
    port: int
    tls_cert: str | None
    tls_key: str | None


def _relative(base: Path, value: str | None) -> str | None:
    """Paths in the file are relative to the file, so a config directory can move as a whole."""
    if value is None or value == ":memory:":
        return value
    p = Path(value).expanduser()
    return str(p if p.is_absolute() else base / p)


def parse_station_file(data: dict[str, Any], source: str, base: Path | None = None) -> StationFile:
    try:
        doc = _StationFile.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        got = err.get("input")
        shown = "" if isinstance(got, dict) else f", got {got!r}"
        raise ConfigError(source, dotted(err["loc"]), f"{err['msg']}{shown}") from None
    st = doc.station
    here = base if base is not None else Path(".")
    fields: dict[str, Any] = {"api_keys": tuple(doc.api_keys), "rate_limits": doc.rate_limits}
    fields |= given_settings(
        st,
        (
            ("range", "range_m"),
            ("fov", "fov_deg"),
            ("stale_after", "stale_after_s"),
            ("command_ttl", "command_ttl_s"),
            ("registration_key", "registration_key"),
        ),
    )
    if st.db is not None:
        fields["db_path"] = _relative(here, st.db)
    try:
        settings = StationSettings.model_validate(fields)
    except ValidationError as exc:
        err = exc.errors()[0]
        names = {
            "range_m": "range",
            "fov_deg": "fov",
            "stale_after_s": "stale_after",
            "command_ttl_s": "command_ttl",
            "db_path": "db",
        }
        key = ".".join(str(p) for p in err["loc"])
        raise ConfigError(source, f"station.{names.get(key, key)}", str(err["msg"])) from None
    key_names = [k.name for k in doc.api_keys]
    for dup in sorted({n for n in key_names if key_names.count(n) > 1}):
        raise ConfigError(source, "api_keys.name", f"unique names, {dup!r} is used twice")
    return StationFile(settings, st.host, st.port, _relative(here, st.tls_cert), _relative(here, st.tls_key))


def load_station_file(path: str | Path) -> StationFile:
    p = Path(path)
    return parse_station_file(read_toml_file(p), str(p), p.parent)
