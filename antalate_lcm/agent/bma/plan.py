"""Resolve ``[[bma]]`` config into loaded plugin classes and validated params — or fail with the key.

Everything a BMA could trip on at run time because of the config (an unknown plugin, a bad param,
a misspelt state, a topic remap to nowhere or to the wrong type) is checked here, before any node
starts (docs/design.md §11). The BMA node uses the same plan, so what was validated is what runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from antalate_lcm.agent.bma.arbiter import ActivationRule
from antalate_lcm.base.errors import ConfigError, PluginNotFound
from antalate_lcm.base.plugins import BEHAVIORS, load_plugin
from antalate_lcm.base.shared import shared_value
from antalate_lcm.base.strict import StrictError, validate_strict
from antalate_lcm.core.behavior import Behavior
from antalate_lcm.core.config import BehaviorConfig, BmaConfig, Config
from antalate_lcm.msgs import behavior_state_t, mc_state_t
from antalate_lcm.transports import transport_for
from antalate_lcm.wire.vocabulary import McState, names

MC_STATES: tuple[str, ...] = names(McState)


@dataclass(frozen=True)
class BehaviorPlan:
    """One behavior, ready to instantiate."""

    key: str
    name: str
    plugin: str
    cls: type[Behavior]
    params: BaseModel
    rule: ActivationRule
    #: The behavior's topic name -> the config's topic name, for every topic it declares or remaps.
    topics: dict[str, str]
    tick_hz: float


@dataclass(frozen=True)
class BmaPlan:
    key: str
    config: BmaConfig
    #: ``mc_state_t`` or ``behavior_state_t``: how the state is read from the state topic.
    state_type: type
    behaviors: tuple[BehaviorPlan, ...]


#: Topics a behavior's ``ctx.peers`` is fed from (docs/behaviors.md, "Peers").
PEER_TOPICS = ("TELEMETRY", "MC_STATE")


def peer_readers(config: Config, plans: Sequence[BmaPlan] | None = None) -> list[str]:
    """The keys (``bma[0].behaviors[1]``) of the behaviors that declare ``uses_peers``, in ``plans``
    (the config's arbiters, already resolved) or else in every arbiter of ``config``."""
    if plans is None:
        plans = [plan_bma(config, bma) for bma in config.bma]
    return [b.key for plan in plans for b in plan.behaviors if b.cls.uses_peers]


def check_peer_buses(config: Config, *, whole_swarm: bool, plans: Sequence[BmaPlan] | None = None) -> None:
    """Raise :class:`ConfigError` when a behavior asks for peers that its config cannot let it hear.

    Peers are heard on the bus their TELEMETRY and MC_STATE travel on. memq:// never leaves its
    process: fine when the whole swarm shares the process (``whole_swarm``), a silent split of the
    swarm otherwise (``--processes N``, one agent per host, a BMA in a process of its own).
    """
    readers = peer_readers(config, plans)
    if not readers:
        return
    for topic in PEER_TOPICS:
        bus = config.topic_buses(topic)[0]
        url = config.buses[bus]
        if transport_for(url).in_process and not whole_swarm:
            raise ConfigError(
                config.source,
                f"buses.{bus}",
                f"a bus other processes reach (udpm://, zenoh://) for {topic}, which {readers[0]} "
                f"reads as its peers (uses_peers): {url!r} stays inside one process, and these agents "
                "run in several (--processes, or nodes in processes of their own)",
            )


def validate_bma_config(config: Config) -> None:
    """Check every ``[[bma]]`` of ``config``; raises :class:`ConfigError` naming the dotted key.

    Imports the behavior plugins (that is how their ``Params`` are known), so call it once, before
    starting nodes.
    """
    for bma in config.bma:
        plan_bma(config, bma)


def plan_bma(config: Config, bma: BmaConfig) -> BmaPlan:
    """Resolve one arbiter's config; raises :class:`ConfigError` naming the dotted key."""
    key = _bma_key(config, bma)

    def fail(sub: str, expected: str) -> ConfigError:
        return ConfigError(config.source, f"{key}.{sub}" if sub else key, f"expected {expected}")

    specs = config.topic_specs()
    spec = specs.get(bma.state_topic)
    if spec is None:
        raise fail("state_topic", "a topic name (MC_STATE or one declared in [topics])")
    if spec.msg_type not in (mc_state_t, behavior_state_t):
        raise fail(
            "state_topic",
            f"a topic of type mc_state_t or behavior_state_t, but {bma.state_topic!r} carries {spec.msg_type.__name__}",
        )
    if spec.msg_type is mc_state_t:
        allowed: tuple[str, ...] | None = MC_STATES
        for k, state in enumerate(bma.states):
            if state not in MC_STATES:
                raise fail(f"states[{k}]", f"an mc_state_t state ({', '.join(MC_STATES)}), got {state!r}")
    else:
        for k, state in enumerate(bma.states):
            if not state:
                raise fail(f"states[{k}]", "a non-empty state name")
        allowed = tuple(bma.states) or None

    names: dict[str, int] = {}
    plans: list[BehaviorPlan] = []
    for j, beh in enumerate(bma.behaviors):
        bkey = f"behaviors[{j}]"
        if beh.name in names:
            raise fail(
                f"{bkey}.name",
                f"a name unique in this arbiter, but {beh.name!r} is also behaviors[{names[beh.name]}]",
            )
        names[beh.name] = j
        plans.append(_plan_behavior(config, beh, f"{key}.{bkey}", allowed, bma.state_topic))
    return BmaPlan(key, bma, spec.msg_type, tuple(plans))


def _plan_behavior(
    config: Config, beh: BehaviorConfig, key: str, allowed: tuple[str, ...] | None, state_topic: str
) -> BehaviorPlan:
    def fail(sub: str, expected: str) -> ConfigError:
        return ConfigError(config.source, f"{key}.{sub}", f"expected {expected}")

    def raw(sub: str, message: str) -> ConfigError:
        return ConfigError(config.source, f"{key}.{sub}", message)

    try:
        cls = load_plugin(BEHAVIORS, beh.plugin, base=Behavior)
    except PluginNotFound as exc:
        raise raw("plugin", str(exc)) from None
    assert issubclass(cls, Behavior)  # checked by load_plugin; narrows the type
    params_model = getattr(cls, "Params", None)
    if not (isinstance(params_model, type) and issubclass(params_model, BaseModel)):
        raise fail("plugin", f"a plugin whose Params is a pydantic BaseModel subclass ({beh.plugin!r})")
    try:
        # Strict as the rest of the config, whatever the plugin's model says: "5" is not 5.
        params = shared_params_model(validate_strict(params_model, beh.params))
    except StrictError as exc:
        raise raw(f"params.{exc.key}" if exc.key else "params", exc.message) from None

    activate_on = list(beh.activate_on) or list(cls.activate_on)
    deactivate_on = list(beh.deactivate_on) or ([] if beh.activate_on else list(cls.deactivate_on))
    if not activate_on:
        raise fail("activate_on", f"at least one state (the plugin {beh.plugin!r} has no default)")
    source = "" if beh.activate_on else f" (default of {beh.plugin!r})"
    for field_name, states in (("activate_on", activate_on), ("deactivate_on", deactivate_on)):
        for k, state in enumerate(states):
            if not state:
                raise fail(f"{field_name}[{k}]", "a non-empty state name")
            if allowed is not None and state not in allowed:
                what = "an mc_state_t state" if allowed is MC_STATES else "a state declared in `states`"
                raise fail(
                    f"{field_name}[{k}]",
                    f"{what} of {state_topic} ({', '.join(allowed)}), got {state!r}{source}",
                )
    for k, state in enumerate(deactivate_on):
        if state in activate_on:
            raise fail(f"deactivate_on[{k}]", f"a state not also in activate_on ({state!r} is in both)")

    topics = _plan_topics(config, cls, beh, fail)
    tick_hz = beh.tick_hz or float(cls.tick_hz)
    if tick_hz < 0:
        raise fail("tick_hz", "a rate >= 0")
    return BehaviorPlan(
        key=key,
        name=beh.name,
        plugin=beh.plugin,
        cls=cls,
        params=params,
        rule=ActivationRule.of(activate_on, deactivate_on),
        topics=topics,
        tick_hz=tick_hz,
    )


def shared_params_model(params: BaseModel) -> BaseModel:
    """The process's one instance of a frozen params model equal to ``params``, to the bit (every
    value's repr, the fields set): a thousand agents' behaviors read one object on every tick (10
    a second each), one object in the cache instead of a thousand (`shared_value`). A model that is
    not frozen, or holds a value with no hash (a list), is the behavior's own as before."""
    if not params.model_config.get("frozen"):
        return params  # its behavior may write it
    try:
        return shared_value(params, key=(params, frozenset(params.model_fields_set), repr(vars(params))))
    except TypeError:  # a value with no hash: mutable, kept apart
        return params


def _plan_topics(config: Config, cls: type[Behavior], beh: BehaviorConfig, fail: Any) -> dict[str, str]:
    specs = config.topic_specs()
    declared = dict(cls.topics)
    for name, target in beh.topics.items():
        if declared and name not in declared:
            raise fail(f"topics.{name}", f"a topic {beh.plugin!r} uses ({', '.join(declared)})")
        if target not in specs:
            raise fail(f"topics.{name}", f"a topic of this config ({', '.join(specs)}), got {target!r}")
    mapping: dict[str, str] = {}
    for name in {**declared, **beh.topics}:
        target = beh.topics.get(name, name)
        spec = specs.get(target)
        if spec is None:
            raise fail(
                "topics",
                f"a binding for topic {name!r}, which {beh.plugin!r} uses: declare it in [topics] "
                f'or remap it (topics = {{{name} = "..."}})',
            )
        want = declared.get(name)
        if want is not None and spec.msg_type is not want:
            where = f"topics.{name}" if name in beh.topics else "topics"
            raise fail(
                where,
                f"a topic of type {want.__name__} for {name!r}, but {target!r} carries {spec.msg_type.__name__}",
            )
        mapping[name] = target
    return mapping


def _bma_key(config: Config, bma: BmaConfig) -> str:
    for i, candidate in enumerate(config.bma):
        if candidate is bma or candidate.name == bma.name:
            return f"bma[{i}]"
    return f"bma({bma.name})"


__all__ = ["MC_STATES", "BehaviorPlan", "BmaPlan", "plan_bma", "validate_bma_config"]
