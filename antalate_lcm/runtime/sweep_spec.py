"""The spec of ``antalate sweep``: which parameters take which values, over which seeds (pure: no files
written, no process started; docs/experiments.md, "Sweeps").

::

    config = "swarm.toml"     # the agent config of every run (relative to this file; required)
    script = "script.toml"    # the experiment script (relative to this file; default: a 30 s mission)
    agents = 4                # simulated agents per run (default 1)
    processes = 1             # processes per run (antalate run --processes; default 1)
    spacing = 8.0             # m between simulated homes (default 8)
    seeds = [1, 2, 3, 4, 5]   # the script's seed of each run; or a count: seeds = 5 is 0, 1, 2, 3, 4
    timeout = 600.0           # s one run may take before it is stopped and recorded as failed
                              # (default: the script's mission_time + timeout + 60)
    speed = "max"             # each run on simulated time (antalate run --speed): "max" or N times
                              # real time; a run is then a function of its seed (default: wall clock)

    [parameters]              # each key a list of values; every combination, with every seed, is one run
    "behavior.dovrat_swarm.forward_speed" = [1.0, 2.0]   # a param of every behavior of that plugin
    "config.hlc.default_takeoff_altitude" = [2.0, 5.0]   # any key of the agent config
    "script.broadcast.reception" = [0.5, 1.0]            # any key of the experiment script

A key of ``config.`` or ``script.`` is a dotted path into that TOML document; an array of tables is
indexed by number (``config.bma.0.behaviors.1.tick_hz``, ``script.fault.0.probability``), a missing
table is created. Every run's config and script are built and checked (as ``antalate run`` checks
them) before the first one flies: a bad value is one line naming the sweep file, the parameter and
the value.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.base.strict import StrictError, validate_strict
from antalate_lcm.core.config import Config, check_unique_agent_names, parse_config
from antalate_lcm.runtime.script import DEFAULT_SCRIPT, Script, parse_script

#: What a parameter's key starts with: where its value goes.
PREFIXES = ("behavior", "config", "script")
#: s a run may take beyond its script's mission_time and timeout (start, analysis) by default.
RUN_MARGIN = 60.0

Value = bool | int | float | str


def _is_speed(value: Any) -> bool:
    """A number of times real time (``antalate run --speed N``)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value < math.inf


class SweepSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    config: str = Field(min_length=1)
    script: str | None = Field(default=None, min_length=1)
    agents: int = Field(default=1, ge=1, le=10_000)
    processes: int = Field(default=1, ge=1, le=1024)
    spacing: float = Field(default=8.0, gt=0, allow_inf_nan=False)
    #: A count or a list of seeds (checked by :func:`parse_spec`: a union's errors name its arms).
    seeds: Any = 1
    timeout: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    #: ``antalate run --speed`` of every run: "max" or a number > 0 (None: the wall clock).
    #: (checked by :func:`parse_spec`, as ``seeds``: a union's errors name its arms)
    speed: Any = None
    parameters: dict[str, list[Value]] = Field(default_factory=dict)


@dataclass(frozen=True)
class Point:
    """One run of the sweep: the values of the parameters (in the spec's order) and the seed."""

    index: int
    values: tuple[tuple[str, Value], ...]
    seed: int

    def label(self) -> str:
        return " ".join([*(f"{_short(k)}={v}" for k, v in self.values), f"seed={self.seed}"])


@dataclass(frozen=True)
class Sweep:
    """A checked spec: the base documents it varies and every run, in order."""

    source: str
    spec: SweepSpec
    config_doc: dict[str, Any]
    script_doc: dict[str, Any]
    points: tuple[Point, ...]
    seeds: tuple[int, ...]

    @property
    def parameters(self) -> list[str]:
        return list(self.spec.parameters)

    def run_timeout(self, point: Point) -> float:
        """s the run of ``point`` may take: the spec's timeout, else what its own script allows."""
        if self.spec.timeout is not None:
            return self.spec.timeout
        script = parse_script(self.documents(point)[1], self.source)
        return script.mission_time + script.timeout + RUN_MARGIN

    def documents(self, point: Point) -> tuple[dict[str, Any], dict[str, Any]]:
        """The config and script documents of one run."""
        config, script = copy.deepcopy(self.config_doc), copy.deepcopy(self.script_doc)
        for name, value in point.values:
            apply(config, script, name, value)
        script["seed"] = point.seed
        return config, script


def _short(key: str) -> str:
    return key.rsplit(".", 1)[-1]


def parse_spec(table: dict[str, Any], source: str) -> SweepSpec:
    try:
        spec = validate_strict(SweepSpec, table)
    except StrictError as exc:
        raise ConfigError(source, exc.key, exc.message) from None
    seeds = spec.seeds
    if isinstance(seeds, bool) or not (
        isinstance(seeds, int) or (isinstance(seeds, list) and all(type(x) is int for x in seeds))
    ):
        raise ConfigError(source, "seeds", f"a count, or a list of integer seeds (got {seeds!r})")
    if isinstance(spec.seeds, int):
        if not 1 <= spec.seeds <= 100_000:
            raise ConfigError(
                source, "seeds", f"a count from 1 to 100000, or a list of seeds (got {spec.seeds})"
            )
    else:
        if not spec.seeds:
            raise ConfigError(source, "seeds", "at least one seed")
        bad = next((s for s in spec.seeds if s < 0), None)
        if bad is not None:
            raise ConfigError(source, "seeds", f"seeds >= 0 (got {bad})")
        if len(set(spec.seeds)) != len(spec.seeds):
            raise ConfigError(source, "seeds", "each seed once (a repeated seed repeats a run)")
    if spec.speed not in (None, "max") and not _is_speed(spec.speed):
        raise ConfigError(source, "speed", f'"max" or a number > 0 (got {spec.speed!r})')
    if spec.speed is not None and spec.processes > 1:  # as antalate run --speed refuses it
        raise ConfigError(source, "speed", "simulated time runs in one process: drop processes or speed")
    for name, values in spec.parameters.items():
        key = f"parameters.{json.dumps(name)}"
        prefix, _, rest = name.partition(".")
        if prefix not in PREFIXES or not rest:
            raise ConfigError(source, key, "a key starting behavior.PLUGIN.PARAM, config.KEY or script.KEY")
        if prefix == "behavior" and len(rest.split(".")) != 2:
            raise ConfigError(source, key, "behavior.PLUGIN.PARAM (a plugin name, then one of its params)")
        if any(part == "" for part in rest.split(".")):
            raise ConfigError(source, key, "dotted names without an empty part")
        if name == "script.seed":
            raise ConfigError(source, key, "the seeds are the sweep's own key: seeds = [...]")
        if not values:
            raise ConfigError(source, key, "at least one value")
        bad_float = next((v for v in values if isinstance(v, float) and not math.isfinite(v)), None)
        if bad_float is not None:
            raise ConfigError(source, key, f"finite numbers (got {bad_float})")
    return spec


def expand(spec: SweepSpec) -> tuple[tuple[int, ...], tuple[Point, ...]]:
    """Every combination of the parameters' values (the first parameter varying slowest), each with
    every seed (the seeds innermost), numbered from 0."""
    seeds = tuple(range(spec.seeds)) if isinstance(spec.seeds, int) else tuple(spec.seeds)
    names = list(spec.parameters)
    combos = itertools.product(*(spec.parameters[n] for n in names))
    points: list[Point] = []
    for values in combos:
        for seed in seeds:
            points.append(Point(len(points), tuple(zip(names, values, strict=True)), seed))
    return seeds, tuple(points)


def apply(config: dict[str, Any], script: dict[str, Any], name: str, value: Value) -> None:
    """Set one parameter in the run's documents (raises ``KeyError`` with what is missing)."""
    prefix, _, rest = name.partition(".")
    if prefix == "behavior":
        plugin, param = rest.split(".")
        found = [
            b
            for bma in config.get("bma", [])
            if isinstance(bma, dict)
            for b in bma.get("behaviors", [])
            if isinstance(b, dict) and b.get("plugin") == plugin
        ]
        if not found:
            plugins = sorted(
                {
                    str(b.get("plugin"))
                    for bma in config.get("bma", [])
                    if isinstance(bma, dict)
                    for b in bma.get("behaviors", [])
                    if isinstance(b, dict)
                }
            )
            raise KeyError(
                f"no [[bma.behaviors]] of the config has plugin {plugin!r} (it has: {', '.join(plugins) or 'none'})"
            )
        for behavior in found:
            params = behavior.setdefault("params", {})
            if not isinstance(params, dict):
                raise KeyError(f"the params of {plugin!r} are not a table")
            params[param] = value
        return
    _set_path(config if prefix == "config" else script, rest.split("."), value)


def _set_path(doc: dict[str, Any], parts: list[str], value: Value) -> None:
    node: Any = doc
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        where = ".".join(parts[:i]) or "the document"
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise KeyError(
                    f"{where} is an array of {len(node)}: index it 0..{len(node) - 1} (got {part!r})"
                )
            if last:
                node[int(part)] = value
                return
            node = node[int(part)]
        elif isinstance(node, dict):
            if last:
                node[part] = value
                return
            node = node.setdefault(part, {})
        else:
            raise KeyError(f"{where} is a value, not a table: it has no key {part!r}")


def check_documents(
    spec: SweepSpec, config: dict[str, Any], script: dict[str, Any], source: str
) -> tuple[Config, Script]:
    """Every check ``antalate run`` makes before anything flies, on one run's documents."""
    from antalate_lcm.runtime.agent import swarm_configs, validate
    from antalate_lcm.runtime.experiment_spec import Experiment, check_interference, check_reach, record_bus

    base = parse_config(config, source)
    parsed = parse_script(script, source)
    configs = swarm_configs(base, spec.agents, spacing=spec.spacing)
    check_unique_agent_names(configs, agents=spec.agents)
    for cfg in configs:
        validate(cfg)
    bus = record_bus(base, None)
    processes = min(spec.processes, len(configs))
    check_reach(base, processes, bus)
    exp = Experiment(
        source, agents=spec.agents, processes=processes, spacing=spec.spacing, script_source=source
    )
    check_interference(exp, parsed, configs)
    return base, parsed


def build(
    spec: SweepSpec, config_doc: dict[str, Any], script_doc: dict[str, Any] | None, source: str
) -> Sweep:
    """The checked sweep: each parameter's values alone, then every combination, give a valid run
    (the seeds change no document but the script's seed)."""
    script_doc = script_doc if script_doc is not None else {"mission_time": DEFAULT_SCRIPT.mission_time}
    seeds, points = expand(spec)
    for name, values in spec.parameters.items():
        for i, value in enumerate(values):
            config, script = copy.deepcopy(config_doc), copy.deepcopy(script_doc)
            _checked(spec, config, script, name, value, source, f"parameters.{json.dumps(name)}[{i}]")
    seen: set[tuple[tuple[str, Value], ...]] = set()
    for point in points:
        if point.values in seen or len(spec.parameters) < 2:
            continue
        seen.add(point.values)
        config, script = copy.deepcopy(config_doc), copy.deepcopy(script_doc)
        for name, value in point.values:
            apply(config, script, name, value)
        try:
            check_documents(spec, config, script, "<run>")
        except AntalateError as exc:
            raise ConfigError(source, "parameters", f"the run {point.label()} is refused: {exc}") from None
    if not spec.parameters:
        _checked(spec, copy.deepcopy(config_doc), copy.deepcopy(script_doc), None, None, source, "config")
    return Sweep(source, spec, config_doc, script_doc, points, seeds)


def _checked(
    spec: SweepSpec,
    config: dict[str, Any],
    script: dict[str, Any],
    name: str | None,
    value: Value | None,
    source: str,
    key: str,
) -> None:
    if name is not None and value is not None:
        try:
            apply(config, script, name, value)
        except KeyError as exc:
            raise ConfigError(source, key, str(exc.args[0])) from None
    try:
        check_documents(spec, config, script, "<run>")
    except AntalateError as exc:
        what = f"{value!r} is refused" if name is not None else "the base run is refused"
        raise ConfigError(source, key, f"{what}: {exc}") from None


def dumps_toml(doc: dict[str, Any]) -> str:
    """A TOML document holding ``doc`` (the tables a TOML file gave, with the sweep's values set):
    one ``key = value`` line per top-level key, inner tables inline. JSON's strings, numbers and
    booleans are TOML's, so the values are written as JSON writes them."""
    return "".join(f"{json.dumps(k)} = {_toml_value(v)}\n" for k, v in doc.items())


def _toml_value(value: Any) -> str:
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, bool | int | str) or (isinstance(value, float) and math.isfinite(value)):
        return json.dumps(value)
    raise AntalateError(f"cannot write {value!r} ({type(value).__name__}) to a run's TOML file")
