"""antalate: a multi-agent UAV autonomy framework over LCM (after AntAlate, Dovrat & Bruckstein 2021).

The public API is small; everything else lives in modules named for their job (docs/architecture.md):

- :class:`Buses`, :class:`Context`, :class:`Node` — typed messaging and the node lifecycle;
- :func:`load_config`, :class:`Config` — the validated TOML config;
- :class:`Behavior`, :class:`BehaviorContext` — what a behavior plugin implements and gets;
- :class:`VehicleAdapter`, :class:`VehicleState` — what a vehicle adapter implements;
- :mod:`antalate_lcm.msgs` — the generated LCM message types;
- :class:`AntalateError`, :class:`ConfigError` — errors a user can meet.

Names are imported on first use so that ``antalate --help`` starts fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.deprecation import renamed_names as _renamed_names

__version__ = "0.1.0"

_EXPORTS = {
    "Buses": "antalate_lcm.core.bus",
    "Context": "antalate_lcm.core.node",
    "Node": "antalate_lcm.core.node",
    "Config": "antalate_lcm.core.config",
    "load_config": "antalate_lcm.core.config",
    "Behavior": "antalate_lcm.core.behavior",
    "BehaviorContext": "antalate_lcm.core.behavior",
    "VehicleAdapter": "antalate_lcm.vehicles",
    "VehicleState": "antalate_lcm.vehicles",
    "AntalateError": "antalate_lcm.base.errors",
    "ConfigError": "antalate_lcm.base.errors",
}

__all__ = [
    "AntalateError",
    "VehicleAdapter",
    "VehicleState",
    "Behavior",
    "BehaviorContext",
    "Buses",
    "Config",
    "ConfigError",
    "Context",
    "Node",
    "__version__",
    "load_config",
]

if TYPE_CHECKING:
    from antalate_lcm.base.errors import AntalateError, ConfigError
    from antalate_lcm.core.behavior import Behavior, BehaviorContext
    from antalate_lcm.core.bus import Buses
    from antalate_lcm.core.config import Config, load_config
    from antalate_lcm.core.node import Context, Node
    from antalate_lcm.vehicles import VehicleAdapter, VehicleState


def _export(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'antalate_lcm' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = _renamed_names(__name__, otherwise=_export)
