"""A config resolved into what runs: the vehicle adapter class and each arbiter's behavior classes,
every one with its params validated -- the one place antalate loads plugins.

`plan_agent` is called once per agent before any node starts (``antalate agent|mc|hlc|bma|osc``,
``antalate demo|run|sweep`` and ``antalate_lcm.runtime.agent.validate``); the nodes are then built
from the plan, so what was checked is what flies. A plugin that does not load, or a param its model
rejects, is one `ConfigError` line naming the key the user wrote.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

from antalate_lcm.agent.bma.plan import BmaPlan, plan_bma
from antalate_lcm.base.deprecation import renamed_attribute, renamed_names
from antalate_lcm.base.errors import ConfigError, StrictError
from antalate_lcm.core.config import Config, load_config
from antalate_lcm.vehicles import UnknownAdapterError, VehicleAdapter, load_adapter
from antalate_lcm.vehicles.base import Clock

#: Shown once per config file that still writes the adapter as a ``[hlc.autopilot]`` table.
DEPRECATED_TABLE = (
    "{source}: the [hlc.autopilot] table is deprecated and will stop loading in a future release; "
    'write `autopilot = "{name}"` under [hlc] and its params in [hlc.autopilot_params]'
)


@dataclass(frozen=True)
class AdapterPlan:
    """The adapter class and its params, validated by the adapter's own model."""

    name: str
    cls: type[VehicleAdapter]
    #: As written (adapters take a plain mapping: docs/design.md §7, constructor contract).
    params: Mapping[str, Any]
    #: ``params`` through `VehicleAdapter.params_model`; None for an adapter without one.
    model: BaseModel | None

    def build(self, clock: Clock) -> VehicleAdapter:
        """A new adapter (no I/O until ``connect()``)."""
        return self.cls(dict(self.params), clock=clock)


@dataclass(frozen=True)
class AgentPlan:
    config: Config
    #: The vehicle adapter the ``[hlc] autopilot`` key names.
    adapter: AdapterPlan
    #: One per ``[[bma]]``, in config order.
    bmas: tuple[BmaPlan, ...]

    if not TYPE_CHECKING:  # the old name, one release (issue #26's vocabulary); mypy sees only `adapter`
        autopilot = renamed_attribute("adapter")


def plan_adapter(config: Config) -> AdapterPlan:
    """Load ``[hlc] autopilot`` and validate its params; raises `ConfigError` naming the key written."""
    hlc = config.hlc
    try:
        cls = load_adapter(hlc.autopilot)
    except UnknownAdapterError as exc:
        raise ConfigError(config.source, hlc.autopilot_name_key, str(exc)) from None
    params = hlc.autopilot_params
    model: BaseModel | None = None
    try:
        if cls.params_model is not None:
            model = cls.validate_params(params)
        else:
            cls(params)  # the contract: no I/O before connect(); unknown keys raise ValueError
    except StrictError as exc:
        field = exc.key.split(".", 1)[0].split("[", 1)[0]
        key = hlc.autopilot_param_key(field)
        raise ConfigError(config.source, key + exc.key[len(field) :], exc.message) from None
    except (ValueError, TypeError) as exc:
        raise ConfigError(config.source, hlc.autopilot_param_key(""), str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - a third-party constructor breaking its contract
        raise ConfigError(
            config.source,
            hlc.autopilot_param_key(""),
            f"params the adapter accepts; its constructor failed: {exc!r}",
        ) from None
    if hlc.autopilot_spelling_deprecated:
        warnings.warn(
            DEPRECATED_TABLE.format(source=config.source, name=hlc.autopilot),
            FutureWarning,
            stacklevel=2,
        )
    return AdapterPlan(hlc.autopilot, cls, dict(params), model)


def plan_agent(config: Config) -> AgentPlan:
    """Every plugin of one agent, loaded and checked (behaviors first, in config order, then the adapter)."""
    bmas = tuple(plan_bma(config, bma) for bma in config.bma)
    return AgentPlan(config, plan_adapter(config), bmas)


def load_plan(path: str | Path | None) -> AgentPlan:
    """`load_config` and `plan_agent`: a config file checked in full, plugins included."""
    return plan_agent(load_config(path))


__all__ = ["DEPRECATED_TABLE", "AgentPlan", "AdapterPlan", "load_plan", "plan_agent", "plan_adapter"]

if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
