"""``antalate bridge``'s config file: ``[buses]`` as in an agent config, ``[bridge]`` and ``[security]``
(docs/wan.md); every mistake is a :class:`~antalate_lcm.base.errors.ConfigError` naming the file and key."""

from __future__ import annotations

import re
import sys
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from antalate_lcm.base.errors import ConfigError
from antalate_lcm.transports import bus_url_problem
from antalate_lcm.transports.datagram import MAX_MESSAGE_SIZE

#: Default largest message forwarded (bytes): 1,000 times the largest antalate message in practice.
DEFAULT_MAX_SIZE = 256 * 1024


class ChannelRule(BaseModel):
    """What a rate cap and a size limit share: the channels they apply to and the way they go."""

    model_config = ConfigDict(extra="forbid", strict=True)

    #: Channel regex (whole name), e.g. ``.*/TELEMETRY``.
    channel: str
    #: The bus the messages it applies to go to (the other direction is not affected).
    to: str

    @field_validator("channel")
    @classmethod
    def _regex(cls, v: str) -> str:
        re.compile(v)
        return v


class RateLimit(ChannelRule):
    #: Messages per second per channel at most; the newest waiting one is sent at each slot.
    rate: float = Field(gt=0)


class SizeLimit(ChannelRule):
    #: Largest message (bytes of LCM payload) forwarded on those channels towards ``to``.
    max: int = Field(gt=0, le=MAX_MESSAGE_SIZE)


class BridgeSecurity(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    #: The swarm key (as in the agents' [security]): signs this bridge's liveliness token; without
    #: it, any Zenoh client can take the site's election over (docs/wan.md).
    swarm_key: str = ""
    #: Former keys, accepted for checking the other bridges' tokens during a rotation.
    previous_keys: list[str] = Field(default_factory=list)
    #: s: how far a token's time may be from this host's clock (the hosts need NTP).
    window: float = Field(default=5.0, gt=0, le=300)


class BridgeSection(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    #: The two bus names (from [buses]) to join.
    between: list[str] = Field(min_length=2, max_length=2)
    #: Channel regexes (whole name) to forward; default every channel.
    channels: list[str] = Field(default_factory=lambda: [".*"])
    #: Channel regexes never forwarded (checked after ``channels``).
    exclude: list[str] = Field(default_factory=list)
    #: Seconds a forwarded message is remembered against echoes and duplicates.
    memory: float = Field(default=2.0, gt=0, le=60)
    #: Name of the network this bridge serves: bridges that join the *same* LAN to Zenoh (a
    #: redundant gateway) must share it, bridges of different sites must not. Empty: this bridge's
    #: own random id (safe: never mistakes another site's messages for its own).
    site: str = ""
    limit: list[RateLimit] = Field(default_factory=list)
    #: Largest message (bytes) forwarded either way unless a [[bridge.size]] says otherwise; far
    #: below liblcm's 256 MiB: the largest antalate message is a few hundred bytes.
    max_size: int = Field(default=DEFAULT_MAX_SIZE, gt=0, le=MAX_MESSAGE_SIZE)
    size: list[SizeLimit] = Field(default_factory=list)

    @field_validator("channels", "exclude")
    @classmethod
    def _regexes(cls, v: list[str]) -> list[str]:
        for pattern in v:
            re.compile(pattern)
        return v


class BridgeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    buses: dict[str, str]
    bridge: BridgeSection
    security: BridgeSecurity = Field(default_factory=BridgeSecurity)

    @field_validator("buses")
    @classmethod
    def _urls(cls, v: dict[str, str]) -> dict[str, str]:
        problem = bus_url_problem(v)
        if problem is not None:
            raise ValueError(f"{problem[0]}: expected {problem[1]}")
        return v

    @model_validator(mode="after")
    def _known(self) -> BridgeConfig:
        a, b = self.bridge.between
        if a == b:
            raise ValueError(f"bridge.between: two different buses, not {a!r} twice")
        for name in (a, b):
            if name not in self.buses:
                raise ValueError(f"bridge.between: a bus declared in [buses], not {name!r}")
        if self.buses[a] == self.buses[b]:
            raise ValueError(f"bridge.between: {a} and {b} are the same bus ({self.buses[a]})")
        for i, lim in enumerate(self.bridge.limit):
            if lim.to not in (a, b):
                raise ValueError(f"bridge.limit[{i}].to: one of {a}, {b}, not {lim.to!r}")
        for i, size in enumerate(self.bridge.size):
            if size.to not in (a, b):
                raise ValueError(f"bridge.size[{i}].to: one of {a}, {b}, not {size.to!r}")
        return self


def load_bridge_config(path: str | Path) -> BridgeConfig:
    """Read and check a bridge config; every mistake is a ConfigError naming the file and key."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - exercised only on 3.10
        import tomli as tomllib

    source = str(path)
    try:
        data = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(source, "", "no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML ({exc})") from None
    try:
        return BridgeConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"])
        msg = str(err["msg"]).removeprefix("Value error, ")
        named = re.match(r"([a-z_]+(?:\.[a-z_]+|\[\d+\]\.[a-z_]+)*): (.*)", msg, re.S)
        if named:  # our own checks name their key first
            key, msg = named.group(1), named.group(2)
        raise ConfigError(source, key, msg) from None
    except re.error as exc:
        raise ConfigError(source, "bridge", f"valid regular expressions ({exc})") from None


__all__ = [
    "DEFAULT_MAX_SIZE",
    "BridgeConfig",
    "BridgeSecurity",
    "BridgeSection",
    "ChannelRule",
    "RateLimit",
    "SizeLimit",
    "load_bridge_config",
]
