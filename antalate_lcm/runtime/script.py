"""The experiment script of ``antalate run``: what the scripted operator does, as a small TOML file.

::

    mission_time = 60.0       # s the whole swarm stays in MISSION before RTL (required)
    altitude = 0.0            # take-off altitude, m above home; 0 = the HLC's default
    timeout = 180.0           # s allowed for take-off and the return together, beyond mission_time

    [[direction]]             # optional, any number, in order of `at`
    at = 10.0                 # s after the whole swarm entered MISSION
    azimuth = 45.0            # deg, 0 = north, clockwise
    speed = 1.0               # m/s
    active = true             # false = stop steering from `at` on

    seed = 0                  # seed of every random draw below (fault probabilities, losses)

    [[fault]]                 # optional, any number: docs/experiments.md, "Faults"
    kind = "crash"            # crash|freeze|sensor|byzantine|battery|link_loss|packet_loss|vehicle
    agent = "sim-03"          # an agent, a list of agents, or "*" (every agent)
    at = 12.0                 # s after the whole swarm entered MISSION
    at_latest = 20.0          # optional: each agent's time drawn in [at, at_latest] from the seed
    since = "mission"         # or "start": at counts from the start of the run (before take-off)
    probability = 1.0         # each agent named is hit with this probability

    [broadcast]               # optional: lossy broadcast control (Segall & Bruckstein)
    reception = 0.7           # probability each agent hears each SWARM/... message

    [analyze]                 # optional: the metrics printed at the end (antalate analyze's options)
    radius_below = 5.0        # m: report when the swarm radius first falls below
    radius_above = 30.0       # m: ... first rises above
    range = 10.0              # m: range of the proximity graph (connectivity)

Values are strict as in every antalate config (``"60"`` is not a number); an unknown key, a
negative time or a non-finite number stops ``antalate run`` before anything flies, with one line
naming the file and the key. The same file without a path: :data:`DEFAULT_SCRIPT`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.base.errors import ConfigError
from antalate_lcm.base.strict import StrictError, validate_strict
from antalate_lcm.core.config import read_toml_file
from antalate_lcm.wire.topics import TOPICS
from antalate_lcm.wire.vocabulary import McState

FaultKind = Literal[
    "crash", "freeze", "sensor", "byzantine", "battery", "link_loss", "packet_loss", "vehicle"
]
#: Every agent of the experiment, in a fault's ``agent``.
EVERY_AGENT = "*"


class DirectionStep(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    at: float = Field(ge=0, allow_inf_nan=False)
    azimuth: float = Field(ge=-360, le=360, allow_inf_nan=False)
    speed: float = Field(default=1.0, ge=0, allow_inf_nan=False)
    active: bool = True


class FaultStep(BaseModel):
    """One ``[[fault]]``: what happens to which agents when (the keys each kind takes: :data:`_KIND_KEYS`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: FaultKind
    agent: str | tuple[str, ...]
    at: float = Field(ge=0, allow_inf_nan=False)
    #: With it, each agent's fault comes at a time drawn uniformly in [at, at_latest] from the seed.
    at_latest: float | None = Field(default=None, ge=0, allow_inf_nan=False)
    #: What ``at`` counts from: the whole swarm in MISSION, or the start of the run (before take-off).
    since: Literal["mission", "start"] = "mission"
    #: s the fault lasts; 0 = to the end of the run.
    duration: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    probability: float = Field(default=1.0, ge=0, le=1, allow_inf_nan=False)
    sensor: Literal["position", "peers"] | None = None
    mode: Literal["stuck", "bias"] | None = None
    #: m north, east added to the position (a biased position sensor, a byzantine agent's lie).
    offset: tuple[float, float] | None = None
    range_bias: float | None = Field(default=None, allow_inf_nan=False)
    bearing_bias: float | None = Field(default=None, ge=-360, le=360, allow_inf_nan=False)
    #: The MC state a byzantine agent claims (a name of :class:`~antalate_lcm.wire.vocabulary.McState`).
    state: str | None = None
    level: float | None = Field(default=None, ge=0, le=100, allow_inf_nan=False)
    drain: float | None = Field(default=None, ge=0, le=6000, allow_inf_nan=False)
    topics: tuple[str, ...] = ()
    loss: float = Field(default=0.0, ge=0, le=1, allow_inf_nan=False)
    delay: float = Field(default=0.0, ge=0, le=60, allow_inf_nan=False)
    direction: Literal["in", "out", "both"] = "both"
    #: Bytes per second the topics may carry together, each way (a token bucket; beyond it a
    #: message is lost), and the bytes it lets through at once (default: one second's worth).
    bandwidth: float | None = Field(default=None, gt=0, le=1e9, allow_inf_nan=False)
    burst: float | None = Field(default=None, gt=0, le=1e9, allow_inf_nan=False)
    #: A fault of the sim vehicle itself (antalate_lcm/vehicles/sim/faults.py).
    vehicle: Literal["failsafe", "pilot_takeover", "link_loss", "state_error"] | None = None
    failsafe: Literal["rtl", "land", "brake"] = "rtl"

    def agents(self, names: list[str]) -> list[str]:
        """The agents this fault names, among ``names`` (``"*"``: all of them)."""
        wanted = (self.agent,) if isinstance(self.agent, str) else self.agent
        return list(names) if EVERY_AGENT in wanted else [n for n in names if n in wanted]


_COMMON = {"kind", "agent", "at", "at_latest", "since", "probability"}
#: The keys each kind takes beyond ``kind, agent, at, probability``.
_KIND_KEYS: dict[str, set[str]] = {
    "crash": set(),
    "freeze": {"duration"},
    "sensor": {"duration", "sensor", "mode", "offset", "range_bias", "bearing_bias"},
    "byzantine": {"duration", "offset", "state"},
    "battery": {"level", "drain"},
    "link_loss": {"duration"},
    "packet_loss": {"duration", "topics", "loss", "delay", "direction", "bandwidth", "burst"},
    "vehicle": {"duration", "vehicle", "failsafe"},
}
#: Vehicle faults that happen once (the others last ``duration`` s).
VEHICLE_EVENTS = frozenset({"failsafe", "pilot_takeover"})


def _check_fault(f: FaultStep) -> tuple[str, str] | None:
    """The first key of a fault its kind does not take or lacks, and why; None when it is whole."""
    given = f.model_fields_set
    for key in sorted(given - _COMMON - _KIND_KEYS[f.kind]):
        return (
            key,
            f"not a key of a {f.kind} fault (it takes {', '.join(sorted(_KIND_KEYS[f.kind])) or 'none'})",
        )
    if f.kind == "sensor":
        if f.sensor is None:
            return "sensor", "which sensor: position or peers"
        if f.mode is None:
            return "mode", "stuck or bias"
        bias_keys = {"offset"} if f.sensor == "position" else {"range_bias", "bearing_bias"}
        other = {"offset", "range_bias", "bearing_bias"} - bias_keys
        for key in sorted(given & other):
            return key, f"not a key of a {f.sensor} sensor fault"
        if f.mode == "bias" and not given & bias_keys:
            return "mode", f"a bias needs {' or '.join(sorted(bias_keys))}"
        if f.mode == "stuck" and given & bias_keys:
            return sorted(given & bias_keys)[0], "a stuck sensor takes no bias"
    elif f.kind == "byzantine":
        if not given & {"offset", "state"}:
            return "kind", "a byzantine fault needs offset (a false position) or state (a false MC state)"
        if f.state is not None and f.state not in McState.__members__:
            return "state", f"one of {', '.join(McState.__members__)} (got {f.state!r})"
    elif f.kind == "battery":
        if not given & {"level", "drain"}:
            return "kind", "a battery fault needs level (percent, at once) or drain (percent/min)"
    elif f.kind == "vehicle":
        if f.vehicle is None:
            return "vehicle", "failsafe, pilot_takeover, link_loss or state_error"
        if "failsafe" in given and f.vehicle != "failsafe":
            return "failsafe", f"only with vehicle = 'failsafe' (got {f.vehicle!r})"
        if "duration" in given and f.vehicle in VEHICLE_EVENTS:
            return "duration", f"a {f.vehicle} happens once: no duration"
    elif f.kind == "packet_loss":
        if not f.topics:
            return "topics", f"the topics it hits, of {', '.join(TOPICS)}"
        unknown = next((t for t in f.topics if t not in TOPICS), None)
        if unknown is not None:
            return "topics", f"topics of {', '.join(TOPICS)} (got {unknown!r})"
        if f.loss == 0.0 and f.delay == 0.0 and f.bandwidth is None:
            return "loss", "a loss probability > 0, a delay > 0 or a bandwidth (bytes/s)"
        if f.burst is not None and f.bandwidth is None:
            return "burst", "a burst with a bandwidth (bytes/s)"
    if isinstance(f.agent, tuple) and not f.agent:
        return "agent", "at least one agent"
    return None


class BroadcastOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    #: Probability that one agent hears one broadcast (SWARM/...) message, each agent and message
    #: independently (simulated agents only).
    reception: float = Field(default=1.0, ge=0, le=1, allow_inf_nan=False)


class AnalyzeOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    radius_below: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    radius_above: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    range_m: float = Field(default=10.0, gt=0, allow_inf_nan=False, alias="range")


class Script(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    mission_time: float = Field(gt=0, allow_inf_nan=False)
    altitude: float = Field(default=0.0, ge=0, le=500, allow_inf_nan=False)
    timeout: float = Field(default=180.0, gt=0, allow_inf_nan=False)
    direction: tuple[DirectionStep, ...] = ()
    seed: int = Field(default=0, ge=0)
    fault: tuple[FaultStep, ...] = ()
    broadcast: BroadcastOptions = BroadcastOptions()
    analyze: AnalyzeOptions = AnalyzeOptions()

    @property
    def interferes(self) -> bool:
        """Whether the script injects faults or loses broadcasts (simulated agents in this process)."""
        return bool(self.fault) or self.broadcast.reception < 1.0


#: The script when none is given: a 30 s mission, no direction, RTL.
DEFAULT_SCRIPT = Script(mission_time=30.0)


def parse_script(table: dict[str, object], source: str) -> Script:
    """The validated script, or a :class:`ConfigError` naming ``source`` and the key."""
    try:
        script = validate_strict(Script, table)
    except StrictError as exc:
        raise ConfigError(source, exc.key, exc.message) from None
    times = [d.at for d in script.direction]
    if times != sorted(times):
        i = next(i for i in range(1, len(times)) if times[i] < times[i - 1])
        raise ConfigError(
            source, f"direction[{i}].at", f"times in order (got {times[i]:g} after {times[i - 1]:g})"
        )
    late = next((i for i, d in enumerate(script.direction) if d.at >= script.mission_time), None)
    if late is not None:
        raise ConfigError(
            source,
            f"direction[{late}].at",
            f"a time within the mission, below mission_time = {script.mission_time:g} "
            f"(got {script.direction[late].at:g})",
        )
    for i, f in enumerate(script.fault):
        problem = _check_fault(f)
        if problem is not None:
            raise ConfigError(source, f"fault[{i}].{problem[0]}", problem[1])
        if f.at_latest is not None and f.at_latest < f.at:
            raise ConfigError(
                source, f"fault[{i}].at_latest", f"a time from at = {f.at:g} on (got {f.at_latest:g})"
            )
        for key, t in (("at", f.at), ("at_latest", f.at_latest)):
            if f.since == "mission" and t is not None and t >= script.mission_time:
                raise ConfigError(
                    source,
                    f"fault[{i}].{key}",
                    f"a time within the mission, below mission_time = {script.mission_time:g} (got {t:g}; "
                    "since = 'start' counts from the start of the run)",
                )
    return script


def check_fault_agents(script: Script, names: list[str], source: str) -> None:
    """Every agent a fault names flies in the experiment (a typo would hit nobody, silently)."""
    for i, f in enumerate(script.fault):
        wanted = (f.agent,) if isinstance(f.agent, str) else f.agent
        unknown = next((a for a in wanted if a != EVERY_AGENT and a not in names), None)
        if unknown is not None:
            shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
            raise ConfigError(
                source, f"fault[{i}].agent", f"an agent of the experiment ({shown}), or '*' (got {unknown!r})"
            )


def load_script(path: str | Path | None) -> Script:
    """Read and validate a script file; None gives :data:`DEFAULT_SCRIPT`."""
    if path is None:
        return DEFAULT_SCRIPT
    p = Path(path)
    return parse_script(read_toml_file(p), str(p))
