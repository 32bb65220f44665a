"""The TOML config (docs/design.md §11), validated in full before any node starts.

``load_config(path)`` returns a :class:`Config` or raises :class:`ConfigError` naming the file, the
dotted key and what was expected, so a typo never surfaces as a crash in the middle of a flight.
"""

from __future__ import annotations

import json
import re
import secrets
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ModelWrapValidatorHandler,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)

from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.base.strict import describe, dotted, find_datetime
from antalate_lcm.transports import EXAMPLES as LCM_URL_EXAMPLES
from antalate_lcm.transports import bus_url_problem
from antalate_lcm.wire.topics import MESSAGE_TYPES, TOPICS, TopicSpec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on 3.10
    import tomli as tomllib

_AGENT_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")
DEFAULT_LAN_URL = "udpm://239.255.76.67:7667?ttl=1"
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Percent = Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)]


class _KeyedError(ValueError):
    """Raised inside a validator to name the dotted key itself (pydantic's location stops at the field)."""

    def __init__(self, key: str, expected: str, *, plain: bool = False) -> None:
        super().__init__(expected)
        self.key = key
        #: What was expected, or with ``plain`` the whole message (pydantic's own words).
        self.expected = expected
        self.plain = plain


class _Section(BaseModel):
    # strict: "5" is not a number and "yes" not a boolean (an int still fills a float).
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


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
    model_config = ConfigDict(extra="allow", frozen=True, strict=True)

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
            elif isinstance(value, str | list | dict):
                try:
                    out[key] = TopicBinding.model_validate(
                        value if isinstance(value, dict) else {"bus": value}
                    )
                except ValidationError as exc:
                    err = describe(exc)
                    sub = err.key if isinstance(value, dict) else err.key.removeprefix("bus").lstrip(".")
                    where = f"topics.{key}{'' if not sub or sub.startswith('[') else '.'}{sub}"
                    raise _KeyedError(where, err.message, plain=True) from None
            else:
                raise _KeyedError(
                    f"topics.{key}",
                    f"a bus name, a list of bus names or a table {{bus, channel, type}}, got {value!r}",
                )
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
    #: Parameters handed to the autopilot adapter, as written ([hlc.autopilot_params] table).
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

    #: Where the user wrote the adapter's name (``hlc.autopilot``, ``hlc.autopilot.name`` or
    #: ``hlc.adapter``), so a bad name is reported at the key they typed.
    _autopilot_name_key: str = PrivateAttr(default="hlc.autopilot")
    #: The keys of a deprecated ``[hlc.autopilot]`` table, None when the canonical spelling was used:
    #: a bad param is reported in the table that holds it.
    _autopilot_table: frozenset[str] | None = PrivateAttr(default=None)

    @model_validator(mode="wrap")
    @classmethod
    def _split_autopilot_table(cls, data: Any, handler: ModelWrapValidatorHandler[HlcConfig]) -> HlcConfig:
        # One canonical spelling: `autopilot = "sim"` with `[hlc.autopilot_params]`. The earlier
        # `[hlc.autopilot]` table (docs/design.md's first draft: `name = "sim"` in it, or
        # `adapter = "sim"` beside it, or neither for the sim) still loads, with a warning from
        # `antalate_lcm.agent.plan` (docs/design.md §11, "Config").
        table_keys: frozenset[str] | None = None
        name_key = "hlc.autopilot"
        if isinstance(data, dict) and isinstance(data.get("autopilot"), dict):
            data = dict(data)
            table = dict(data.pop("autopilot"))
            table_keys = frozenset(table)
            if "name" in table:
                name_key = "hlc.autopilot.name"
            elif "adapter" in data:
                name_key = "hlc.adapter"
            name = table.pop("name", data.pop("adapter", "sim"))
            data["autopilot"] = name
            data["autopilot_params"] = {**table, **data.get("autopilot_params", {})}
        model = handler(data)
        model._autopilot_name_key = name_key
        model._autopilot_table = table_keys
        return model

    @property
    def autopilot_name_key(self) -> str:
        return self._autopilot_name_key

    def autopilot_param_key(self, field: str) -> str:
        """The dotted key of the adapter param ``field`` ("" = the table itself), in the table the user wrote."""
        table = self._autopilot_table
        in_table = table is not None and (field in table or field not in self.autopilot_params)
        prefix = "hlc.autopilot" if in_table else "hlc.autopilot_params"
        return f"{prefix}.{field}" if field else prefix

    @property
    def autopilot_spelling_deprecated(self) -> bool:
        """Whether the adapter was given by a ``[hlc.autopilot]`` table, not the canonical spelling."""
        return self._autopilot_table is not None


class FenceConfig(_Section):
    """The swarm's geofence ([safety.fence], docs/safety.md): a polygon, a floor and a ceiling."""

    #: Vertices as [north, east] metres from [safety] origin (needs `origin`)...
    polygon: list[
        Annotated[list[Annotated[float, Field(allow_inf_nan=False)]], Field(min_length=2, max_length=2)]
    ] = Field(default_factory=list)
    #: ... or as [lat, lon] degrees WGS84 (one of the two).
    polygon_wgs84: list[
        Annotated[list[Annotated[float, Field(allow_inf_nan=False)]], Field(min_length=2, max_length=2)]
    ] = Field(default_factory=list)
    floor: NonNegative = 0.0  # m above home
    ceiling: Positive = 120.0  # m above home
    margin: NonNegative = 2.0  # m kept from every edge, the floor and the ceiling
    #: A vehicle found outside: fly back in ("return"), "land" or "hover".
    outside: Literal["return", "land", "hover"] = "return"

    @model_validator(mode="after")
    def _one_polygon(self) -> FenceConfig:
        if bool(self.polygon) == bool(self.polygon_wgs84):
            raise _KeyedError(
                "safety.fence.polygon", "either polygon ([north, east] m) or polygon_wgs84, not both"
            )
        for lat, _lon in self.polygon_wgs84:
            if not -90.0 <= lat <= 90.0:
                raise _KeyedError("safety.fence.polygon_wgs84", f"latitudes in [-90, 90], got {lat!r}")
        try:
            self.geofence(self.polygon_wgs84[0] if self.polygon_wgs84 else [0.0, 0.0])
        except ValueError as exc:
            key = "safety.fence.polygon_wgs84" if self.polygon_wgs84 else "safety.fence.polygon"
            raise _KeyedError(key, str(exc), plain=True) from None
        return self

    def geofence(self, origin: Sequence[float]) -> Geofence:
        """The fence in the local frame at ``origin`` ([lat, lon]); ValueError when it is not a simple polygon."""
        if self.polygon:
            points = tuple((float(n), float(e)) for n, e in self.polygon)
        else:
            frame = FlatFrame(float(origin[0]), float(origin[1]))
            points = tuple(frame.to_ne(lat, lon) for lat, lon in self.polygon_wgs84)
        return Geofence(points, self.floor, self.ceiling, self.margin)


class SafetyConfig(_Section):
    """Separation and geofence below every behavior ([safety], docs/safety.md). Empty values take
    the vehicle's defaults (`antalate_lcm.agent.hlc.safety_params`)."""

    #: Off by default: every HLC then listens to the whole swarm's telemetry (docs/safety.md, cost).
    enabled: bool = False
    radius: Annotated[float | None, Field(gt=0, allow_inf_nan=False)] = None  # m, horizontal
    vertical: Annotated[float | None, Field(gt=0, allow_inf_nan=False)] = None  # m, half-height
    gamma: Positive = 2.0  # 1/s, the barrier's rate
    #: s, the vehicle's velocity response time constant (the positions' lead); default per vehicle.
    lead: Annotated[float | None, Field(ge=0, allow_inf_nan=False)] = None
    #: m/s, the fastest a peer may fly (stale peers' growing balls); default hlc.max_horizontal_speed.
    peer_speed: Annotated[float | None, Field(gt=0, allow_inf_nan=False)] = None
    stale_after: Positive = 1.0  # s: an older peer report is stale
    forget_after: Positive = 30.0  # s: an older one is dropped
    #: Fewer fresh peers than this is "no peer information" (0: a lone agent is fine).
    min_peers: Annotated[int, Field(ge=0)] = 0
    no_peers: Literal["hover", "continue", "land"] = "hover"
    #: [lat, lon] of the local frame (a local fence needs it); default: the vehicle's first position.
    origin: list[Annotated[float, Field(allow_inf_nan=False)]] = Field(default_factory=list)
    #: RTL: "filtered" (the HLC flies home through the filter, then lands) or "autopilot" (the
    #: vehicle's own RTL: not deconflicted, docs/safety.md).
    rtl: Literal["filtered", "autopilot"] = "filtered"
    rtl_speed: Positive = 3.0  # m/s, the filtered return leg
    fence: FenceConfig | None = None

    @model_validator(mode="after")
    def _checks(self) -> SafetyConfig:
        if self.origin and (len(self.origin) != 2 or not -90.0 <= self.origin[0] <= 90.0):
            raise _KeyedError("safety.origin", f"[lat, lon] in degrees, got {self.origin!r}")
        if self.fence is not None and self.fence.polygon and not self.origin:
            raise _KeyedError("safety.origin", "[lat, lon]: a fence in [north, east] metres needs its origin")
        if self.forget_after < self.stale_after:
            raise _KeyedError("safety.forget_after", f"at least stale_after ({self.stale_after:g} s)")
        return self


class OscConfig(_Section):
    enabled: bool = False
    #: Base URL of the station, e.g. "http://127.0.0.1:8080" (the OSC POSTs to {server}/api/report).
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

    @field_validator("server")
    @classmethod
    def _station_url(cls, v: str) -> str:
        problem = station_url_problem(v)
        if problem:
            raise _KeyedError("osc.server", f"{problem}, got {v!r}")
        return v


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
    #: s before a behavior that raised is restarted while the state still activates it; doubled
    #: for each failure in a row (up to 60 s). 0 = it stays down until the state leaves and comes back.
    restart_backoff: NonNegative = 2.0


class SecurityConfig(_Section):
    #: Shared swarm key (text). Empty = commands are not authenticated.
    swarm_key: str = ""
    #: Accepted age of a signed command (s), against replay.
    window: Positive = 5.0
    #: Allow internal topics (MC_STATE, HLC_STATE, VELOCITY_CMD, ...) on a network-reachable bus with
    #: no swarm key. Anyone on that network can then move the vehicle; the node says so loudly.
    insecure: bool = False
    #: Former keys, accepted for verification only (never for signing) during a key rotation.
    previous_keys: list[str] = Field(default_factory=list)
    #: Directory of the replay memory (per-sender high-water utime of accepted operator inputs).
    #: Empty = $XDG_STATE_HOME/antalate, or nothing at all when every bus is memq:// or file://.
    state_dir: str = ""


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    agent: AgentConfig = Field(default_factory=AgentConfig)
    buses: dict[str, str] = Field(default_factory=lambda: {"lan": DEFAULT_LAN_URL})
    topics: TopicsConfig = Field(default_factory=TopicsConfig)
    mc: McConfig = Field(default_factory=McConfig)
    hlc: HlcConfig = Field(default_factory=HlcConfig)
    osc: OscConfig = Field(default_factory=OscConfig)
    bma: list[BmaConfig] = Field(default_factory=list)
    security: SecurityConfig = Field(default_factory=SecurityConfig)
    safety: SafetyConfig = Field(default_factory=SafetyConfig)
    #: Path of the file this came from (for messages); not a TOML key.
    source: str = Field(default="<defaults>", exclude=True)

    @field_validator("buses")
    @classmethod
    def _urls(cls, v: dict[str, str]) -> dict[str, str]:
        problem = bus_url_problem(v)
        if problem is not None:
            raise _KeyedError(*problem)
        if not v:
            raise _KeyedError(
                "buses", f"at least one bus, e.g. lan = {DEFAULT_LAN_URL!r} ({LCM_URL_EXAMPLES})"
            )
        return v

    @model_validator(mode="after")
    def _cross_checks(self) -> Config:
        known = set(self.buses)
        if self.topics.default_bus not in known:
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
                raise _KeyedError(
                    f"bma[{i}].state_topic", "a topic name (MC_STATE or one declared in [topics])"
                )
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

    def watched_bus(self, name: str | None) -> str:
        """The bus a tool that watches the swarm opens (``antalate log``, the recording of ``antalate
        run``, the Foxglove bridge): ``name`` (its ``--bus``), else ``lan`` if declared, else the
        default bus."""
        return name or ("lan" if "lan" in self.buses else self.topics.default_bus)

    def bus_url(self, name: str) -> str:
        """The URL of the bus a tool was told to open; an undeclared name is refused, naming those
        declared (the name comes from a command line, not from this file)."""
        url = self.buses.get(name)
        if url is None:
            raise AntalateError(f"no bus named {name!r} in {self.source}; declared: {', '.join(self.buses)}")
        return url

    def with_agent_name(self, name: str) -> Config:
        return self.model_copy(update={"agent": AgentConfig(name=name)})


def station_url_problem(url: str) -> str | None:
    """Why ``url`` cannot be the OSC's station base URL, or None (http(s)://HOST[:PORT][/PATH])."""
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        return "an http:// or https:// URL with a port 1-65535"
    if parts.scheme not in ("http", "https"):
        return "an http:// or https:// URL such as 'http://127.0.0.1:8080'"
    if not parts.hostname:
        return "an http:// or https:// URL with a host, such as 'http://127.0.0.1:8080'"
    if port is not None and not 1 <= port <= 65535:
        return "an http:// or https:// URL with a port 1-65535"
    if parts.query or parts.fragment:
        return "a base URL without ?query or #fragment (the OSC appends /api/report)"
    return None


def anonymous_token() -> str:
    """A random agent name for anonymous swarms: short, channel-safe and unlikely to collide."""
    return "anon-" + secrets.token_hex(4)


def parse_config(data: dict[str, Any], source: str = "<config>") -> Config:
    """Validate an already-parsed TOML document; see :func:`load_config`.

    Strict throughout: values are taken as TOML typed them (see `antalate_lcm.base.strict`). Plugins
    (the vehicle adapter, behaviors) are not imported here: `antalate_lcm.agent.plan.plan_agent` resolves
    them and validates their params, the one place that does, so a config is data and nothing else.
    """
    where = find_datetime(data)
    if where is not None:
        raise ConfigError(source, dotted(where), "a TOML date/time is not a valid value here")
    if "source" in data:
        raise ConfigError(source, "source", "Extra inputs are not permitted (not a config key)")
    try:
        text = json.dumps({**data, "source": source})
    except (TypeError, ValueError) as exc:  # only a Python caller can get here
        raise ConfigError(source, "", f"not a TOML document: {exc}") from None
    try:
        config = Config.model_validate_json(text, strict=True)
    except ValidationError as exc:
        ctx_err = (exc.errors()[0].get("ctx") or {}).get("error")
        if isinstance(ctx_err, _KeyedError):
            message = ctx_err.expected if ctx_err.plain else f"expected {ctx_err.expected}"
            raise ConfigError(source, ctx_err.key, message) from None
        err = describe(exc)
        raise ConfigError(source, err.key, err.message) from None
    if not config.agent.name:
        config = config.with_agent_name(anonymous_token())
    return config


def check_unique_agent_names(configs: Sequence[Config], *, agents: int = 1) -> None:
    """One process, one name per agent: two agents with the same name would share every channel.

    Raises `ConfigError` naming the second file and ``agent.name``, and where the first came from.
    ``agents`` is ``antalate agent --agents N``, which names the copies of a config NAME-01, NAME-02...
    """
    seen: dict[str, Config] = {}
    for cfg in configs:
        name = cfg.agent.name
        first = seen.get(name)
        if first is None:
            seen[name] = cfg
            continue
        how = ""
        if agents > 1:
            how = f" (--agents {agents} names the copies of each config NAME-01, NAME-02, ...; an unnamed agent's are sim-01, ...)"
        same = " (the same file twice?)" if first.source == cfg.source else ""
        raise ConfigError(
            cfg.source,
            "agent.name",
            f"a name no other agent of this process has: {name!r} is also an agent of {first.source}{same}{how}",
        )


def load_config(path: str | Path | None) -> Config:
    """Read and validate a config file; ``None`` gives the embedded defaults (one simulated agent)."""
    if path is None:
        return parse_config({}, "<defaults>")
    p = Path(path)
    return parse_config(read_toml_file(p), str(p))


def read_toml_file(p: Path) -> dict[str, Any]:
    """A TOML file as a table, or the one-line `ConfigError` a person can act on (every config file
    antalate reads: nodes' and the station's)."""
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(p), "", "file not found") from None
    except OSError as exc:
        raise ConfigError(str(p), "", f"cannot be read: {exc.strerror}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), "", f"is not valid TOML: {exc}") from None


__all__ = [
    "AgentConfig",
    "BehaviorConfig",
    "BmaConfig",
    "Config",
    "ConfigError",
    "FenceConfig",
    "HlcConfig",
    "McConfig",
    "OscConfig",
    "SafetyConfig",
    "SecurityConfig",
    "TopicBinding",
    "TopicsConfig",
    "anonymous_token",
    "check_unique_agent_names",
    "load_config",
    "parse_config",
    "station_url_problem",
]
