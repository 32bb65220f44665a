"""The TOML config (docs/design.md §11), validated in full before any node starts.

``load_config(path)`` returns a :class:`Config` or raises :class:`ConfigError` naming the file, the
dotted key and what was expected, so a typo never surfaces as a crash in the middle of a flight.
"""

from __future__ import annotations

import re
import secrets
import sys
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from antalate_lcm.errors import ConfigError
from antalate_lcm.topics import MESSAGE_TYPES, TOPICS, TopicSpec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on 3.10
    import tomli as tomllib

_AGENT_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")
DEFAULT_LAN_URL = "udpm://239.255.76.67:7667?ttl=1"
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Percent = Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class AgentConfig(_Section):
    #: Agent name; empty means an anonymous random token (the paper's anonymous agents).
    name: str = ""

    @field_validator("name")
    @classmethod
    def _channel_safe(cls, v: str) -> str:
        # Part of every channel name, and lcm-spy (Java) reads strings byte by byte: plain ASCII only.
        if v and not _AGENT_NAME.fullmatch(v):
            raise ValueError(
                "an agent name is part of channel names: ASCII letters, digits, '-', '_' and '.' only "
                "(no '/' or white space)"
            )
        return v


class TopicBinding(_Section):
    """Where a topic travels. ``bus`` may list several buses: publish to all, subscribe on the first.

    That is how an agent's internal traffic stays on its own host (``local``, ttl=0) while the
    operator still sees its state on the LAN: the link to the operator is not the link between the
    agent's own nodes.
    """

    bus: list[str] | None = None
    channel: str | None = None
    #: Only for new topics a config adds (e.g. a cascaded ``behavior_state_t``): the LCM type name.
    type: str | None = None

    @field_validator("bus", mode="before")
    @classmethod
    def _one_or_many(cls, v: Any) -> Any:
        return [v] if isinstance(v, str) else v


class TopicsConfig(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)

    #: Bus for every topic the config does not bind explicitly.
    default_bus: str = "lan"

    def bindings(self) -> dict[str, TopicBinding]:
        return dict(self.__pydantic_extra__ or {})

    @model_validator(mode="before")
    @classmethod
    def _parse_bindings(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        out: dict[str, Any] = {}
        for key, value in data.items():
            if key == "default_bus":
                out[key] = value
            elif isinstance(value, str | list):
                out[key] = TopicBinding(bus=value)
            elif isinstance(value, dict):
                out[key] = TopicBinding.model_validate(value)
            else:
                raise ValueError(f"{key}: expected a bus name or a table {{bus, channel, type}}")
        return out


class McConfig(_Section):
    takeoff_ack_timeout: Positive = 5.0
    republish_hz: Positive = 5.0
    #: s without an hlc_state_t before the MC reports HLC_LOST (the HLC republishes at 5 Hz).
    hlc_timeout: Positive = 2.0
    #: What the MC does when the HLC's autopilot link comes back after LLC_DOWN with the vehicle
    #: in the air: "rtl" (return home), "land" (land where it is) or "hold" (hover, wait for the operator).
    on_link_regained: Literal["rtl", "land", "hold"] = "rtl"


class HlcConfig(_Section):
    autopilot: str = "sim"
    #: Parameters handed to the autopilot adapter, as written ([hlc.autopilot] table).
    autopilot_params: dict[str, Any] = Field(default_factory=dict)
    telemetry_hz: Positive = 10.0
    republish_hz: Positive = 5.0
    control_hz: Positive = 20.0
    default_takeoff_altitude: Positive = 10.0
    airborne_fraction: Annotated[float, Field(gt=0, le=1)] = 0.95
    gain_altitude_timeout: Positive = 30.0
    low_battery: Percent = 20.0
    #: V per cell at or below which the battery is low (LiPo: 3.5 V loaded is about 15-20% left).
    #: Used when the adapter reports the voltage and the cell count.
    low_cell_voltage: Annotated[float, Field(gt=0, le=5, allow_inf_nan=False)] = 3.5
    link_timeout: Positive = 3.0
    velocity_timeout: Positive = 0.5
    max_horizontal_speed: Positive = 5.0
    max_vertical_speed: Positive = 2.0
    max_yaw_rate: Positive = 90.0

    @model_validator(mode="before")
    @classmethod
    def _split_autopilot_table(cls, data: Any) -> Any:
        # TOML lets users write both `autopilot = "sim"` and `[hlc.autopilot] home_lat = ...`
        # only if the table is named differently; we accept `[hlc.autopilot_params]` and also
        # `autopilot = { name = "sim", ... }` so the DESIGN's `[hlc.autopilot]` table works.
        if isinstance(data, dict) and isinstance(data.get("autopilot"), dict):
            data = dict(data)
            table = dict(data.pop("autopilot"))
            name = table.pop("name", data.pop("adapter", "sim"))
            data["autopilot"] = name
            data["autopilot_params"] = {**table, **data.get("autopilot_params", {})}
        return data


class OscConfig(_Section):
    enabled: bool = False
    #: Base URL of the station, e.g. "http://127.0.0.1:8080".
    server: str = "http://127.0.0.1:8080"
    rate: Positive = 2.0
    timeout: Positive = 2.0
    max_backoff: Positive = 30.0
    max_reply_bytes: Annotated[int, Field(gt=0)] = 65536
    #: PEM file of the CA that signed the station's TLS certificate (https:// servers); empty = the
    #: system's trusted CAs.
    ca_file: str = ""
    #: File where the OSC keeps its station token (mode 0600) so a restarted agent reports under the
    #: same token; empty = memory only (a restart then re-registers: with a swarm key, by proof).
    token_file: str = ""


class BehaviorConfig(_Section):
    plugin: str
    #: Instance name (defaults to the plugin name); shown in arbiter_status_t.active.
    name: str = ""
    activate_on: list[str] = Field(default_factory=list)
    deactivate_on: list[str] = Field(default_factory=list)
    params: dict[str, Any] = Field(default_factory=dict)
    #: Topic remaps: the behavior's topic name -> the config's topic name.
    topics: dict[str, str] = Field(default_factory=dict)
    tick_hz: NonNegative = 0.0

    @model_validator(mode="after")
    def _default_name(self) -> BehaviorConfig:
        if not self.name:
            object.__setattr__(self, "name", self.plugin.rsplit(":", 1)[-1].rsplit(".", 1)[-1])
        return self


class BmaConfig(_Section):
    name: str
    #: The state topic this arbiter follows: MC_STATE or a behavior_state_t topic.
    state_topic: str = "MC_STATE"
    republish_hz: Positive = 5.0
    #: For a behavior_state_t-driven (cascaded) arbiter: the states its behaviors may name, so a
    #: typo fails at load. Empty = any string. MC_STATE arbiters always check mc_state_t's names.
    states: list[str] = Field(default_factory=list)
    behaviors: list[BehaviorConfig] = Field(default_factory=list)


class SecurityConfig(_Section):
    #: Shared swarm key (text). Empty = commands are not authenticated.
    swarm_key: str = ""
    #: Accepted age of a signed command (s), against replay.
    window: Positive = 5.0
    #: Allow internal topics (MC_STATE, HLC_STATE, VELOCITY_CMD, ...) on a network-reachable bus with
    #: no swarm key. Anyone on that network can then move the vehicle; the node says so loudly.
    insecure: bool = False


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    agent: AgentConfig = Field(default_factory=AgentConfig)
    buses: dict[str, str] = Field(default_factory=lambda: {"lan": DEFAULT_LAN_URL})
    topics: TopicsConfig = Field(default_factory=TopicsConfig)
    mc: McConfig = Field(default_factory=McConfig)
    hlc: HlcConfig = Field(default_factory=HlcConfig)
    osc: OscConfig = Field(default_factory=OscConfig)
    bma: list[BmaConfig] = Field(default_factory=list)
    security: SecurityConfig = Field(default_factory=SecurityConfig)
    #: Path of the file this came from (for messages); not a TOML key.
    source: str = Field(default="<defaults>", exclude=True)

    @field_validator("buses")
    @classmethod
    def _urls(cls, v: dict[str, str]) -> dict[str, str]:
        for name, url in v.items():
            if "://" not in url:
                raise ValueError(f"bus {name!r}: expected an LCM URL such as {DEFAULT_LAN_URL!r} or 'memq://'")
        if not v:
            raise ValueError("at least one bus is needed")
        return v

    @model_validator(mode="after")
    def _cross_checks(self) -> Config:
        known = set(self.buses)
        if self.topics.default_bus not in known:
    #: Former keys, accepted for verification only (never for signing) during a key rotation.
    previous_keys: list[str] = Field(default_factory=list)
    #: Directory of the replay memory (per-sender high-water utime of accepted operator inputs).
    #: Empty = $XDG_STATE_HOME/antalate, or nothing at all when every bus is memq:// or file://.
    state_dir: str = ""
            raise _KeyedError("topics.default_bus", f"a bus declared in [buses] ({', '.join(sorted(known))})")
        for topic, binding in self.topics.bindings().items():
            for bus in binding.bus or []:
                if bus not in known:
                    raise _KeyedError(f"topics.{topic}.bus", f"a bus declared in [buses], not {bus!r}")
            if topic not in TOPICS and binding.type is None:
                raise _KeyedError(
                    f"topics.{topic}",
                    f"a known topic ({', '.join(TOPICS)}) or a new one with `type` (an antalate LCM type)",
                )
            if binding.type is not None and binding.type not in MESSAGE_TYPES:
                raise _KeyedError(f"topics.{topic}.type", f"one of {', '.join(MESSAGE_TYPES)}")
            if topic not in TOPICS and binding.channel is None:
                raise _KeyedError(f"topics.{topic}.channel", "a channel template for a new topic")
        names = [b.name for b in self.bma]
        for dup in {n for n in names if names.count(n) > 1}:
            raise _KeyedError("bma.name", f"unique arbiter names, {dup!r} is used twice")
        for i, bma in enumerate(self.bma):
            if bma.state_topic not in self.topic_specs():
                raise _KeyedError(f"bma[{i}].state_topic", "a topic name (MC_STATE or one declared in [topics])")
        return self

    # ----------------------------------------------------------------- derived views
    def topic_specs(self) -> dict[str, TopicSpec]:
        """Every topic this config knows: the built-in table plus the config's own, channels remapped."""
        specs = dict(TOPICS)
        for topic, binding in self.topics.bindings().items():
            base = specs.get(topic)
            msg_type = MESSAGE_TYPES[binding.type] if binding.type else base.msg_type  # type: ignore[union-attr]
            specs[topic] = TopicSpec(msg_type, binding.channel or base.channel)  # type: ignore[union-attr]
        return specs

    def topic_buses(self, topic: str) -> list[str]:
        binding = self.topics.bindings().get(topic)
        if binding is not None and binding.bus:
            return list(binding.bus)
        return [self.topics.default_bus]

    def with_agent_name(self, name: str) -> Config:
        return self.model_copy(update={"agent": AgentConfig(name=name)})


class _KeyedError(ValueError):
    def __init__(self, key: str, expected: str) -> None:
        super().__init__(expected)
        self.key = key
        self.expected = expected


def anonymous_token() -> str:
    """A random agent name for anonymous swarms: short, channel-safe and unlikely to collide."""
    return "anon-" + secrets.token_hex(4)


def _dotted(loc: tuple[Any, ...]) -> str:
    parts: list[str] = []
    for item in loc:
        if isinstance(item, int):
            parts[-1:] = [f"{parts[-1]}[{item}]"] if parts else [f"[{item}]"]
        elif item in ("function-after", "function-before") or str(item).startswith("function-"):
            continue
        else:
            parts.append(str(item))
    return ".".join(parts)


def parse_config(data: dict[str, Any], source: str = "<config>") -> Config:
    """Validate an already-parsed TOML document; see :func:`load_config`."""
    try:
        config = Config.model_validate({**data, "source": source})
    except ValidationError as exc:
        err = exc.errors()[0]
        ctx_err = (err.get("ctx") or {}).get("error")
        if isinstance(ctx_err, _KeyedError):
            raise ConfigError(source, ctx_err.key, f"expected {ctx_err.expected}") from None
        key = _dotted(tuple(err["loc"]))
        got = err.get("input")
        shown = "" if isinstance(got, dict) else f", got {got!r}"
        raise ConfigError(source, key, f"{err['msg']}{shown}") from None
    if not config.agent.name:
        config = config.with_agent_name(anonymous_token())
    return config


def load_config(path: str | Path | None) -> Config:
    """Read and validate a config file; ``None`` gives the embedded defaults (one simulated agent)."""
    if path is None:
        return parse_config({}, "<defaults>")
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(p), "", "file not found") from None
    except OSError as exc:
        raise ConfigError(str(p), "", f"cannot be read: {exc.strerror}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), "", f"is not valid TOML: {exc}") from None
    return parse_config(data, str(p))



__all__ = [
    "AgentConfig",
    "BehaviorConfig",
    "BmaConfig",
    "Config",
    "ConfigError",
    "HlcConfig",
    "McConfig",
    "OscConfig",
    "SecurityConfig",
    "TopicBinding",
    "TopicsConfig",
    "anonymous_token",
    "load_config",
    "parse_config",
]

