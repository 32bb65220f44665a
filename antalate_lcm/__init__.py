"""antalate: a multi-agent UAV autonomy framework over LCM (after AntAlate, Dovrat & Bruckstein 2021).

The public API is small; everything else lives in modules named for their job (docs/architecture.md):

- :class:`Bus`, :class:`Context`, :class:`Node` — typed messaging and the node lifecycle;
- :func:`load_config`, :class:`Config` — the validated TOML config;
- :class:`Behavior`, :class:`BehaviorContext` — what a behavior plugin implements and gets;
- :class:`Autopilot`, :class:`AutopilotState` — what a vehicle adapter implements;
- :mod:`antalate_lcm.msgs` — the generated LCM message types;
- :class:`AntalateError`, :class:`ConfigError` — errors a user can meet.

Names are imported on first use so that ``antalate --help`` starts fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_EXPORTS = {
    "Bus": "antalate_lcm.core.bus",
    "Context": "antalate_lcm.core.node",
    "Node": "antalate_lcm.core.node",
    "Config": "antalate_lcm.core.config",
    "load_config": "antalate_lcm.core.config",
    "Behavior": "antalate_lcm.core.behavior",
    "BehaviorContext": "antalate_lcm.core.behavior",
    "Autopilot": "antalate_lcm.autopilot",
    "AutopilotState": "antalate_lcm.autopilot",
    "AntalateError": "antalate_lcm.base.errors",
    "ConfigError": "antalate_lcm.base.errors",
}

__all__ = [
    "AntalateError",
    "Autopilot",
    "AutopilotState",
    "Behavior",
    "BehaviorContext",
    "Bus",
    "Config",
    "ConfigError",
    "Context",
    "Node",
    "__version__",
    "load_config",
]

if TYPE_CHECKING:
    from antalate_lcm.autopilot import Autopilot, AutopilotState
    from antalate_lcm.base.errors import AntalateError, ConfigError
    from antalate_lcm.core.behavior import Behavior, BehaviorContext
    from antalate_lcm.core.bus import Bus
    from antalate_lcm.core.config import Config, load_config
    from antalate_lcm.core.node import Context, Node


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'antalate_lcm' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
