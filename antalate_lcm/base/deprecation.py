"""The one mechanism behind the old names of moved modules, renamed names and renamed attributes (issue
#26, docs/architecture.md, "Deprecated names"): every shim warns the same way and resolves what its star
import left out the same way, so removing them next release is deleting files and lines, and no shim can
drift from the others. `MOVED_MODULES` and `RENAMED_NAMES` are the one list of what is deprecated by name
(the doc's table is checked against them, tests/architecture/test_deprecated_names.py); strings only, so
this base module imports no layer above it."""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable, Mapping
from typing import Any

#: Every moved public module, old -> new: each old one is a shim file at its old path (the star import of
#: the new one, then ``__getattr__ = moved_module(__name__)``; ``antalate_lcm.autopilot`` also maps its
#: submodules).
MOVED_MODULES: Mapping[str, str] = {
    "antalate_lcm.lcm_datagram": "antalate_lcm.transports.datagram",
    "antalate_lcm.behavior": "antalate_lcm.core.behavior",
    "antalate_lcm.geo": "antalate_lcm.base.geo",
    "antalate_lcm.peers": "antalate_lcm.wire.peers",
    "antalate_lcm.ratelimit": "antalate_lcm.base.ratelimit",
    "antalate_lcm.security": "antalate_lcm.wire.security",
    "antalate_lcm.validation": "antalate_lcm.wire.validation",
    "antalate_lcm.analysis": "antalate_lcm.apps.analysis",
    "antalate_lcm.autopilot": "antalate_lcm.vehicles",
    "operator_tui.link": "operator_tui.node",
    "operator_tui.model": "operator_tui.board",
    "antalate_lcm.apps.analysis.model": "antalate_lcm.apps.analysis.records",
    "antalate_lcm.runtime.commands": "antalate_lcm.runtime.cli",
    "antalate_lcm.runtime.clock_link": "antalate_lcm.runtime.clock_client",
}

#: The vehicle adapter packages (``antalate_lcm.vehicles.<package>``); ``<Package>Adapter`` is each one's class.
_ADAPTER_PACKAGES = ("crazyflie", "mavlink", "px4", "sim", "tello")

#: Every renamed module-level name (issue #26's vocabulary, docs/architecture.md): module -> {old: new}.
#: A module listed here binds ``__getattr__ = renamed_names(__name__)`` under ``if not TYPE_CHECKING``.
RENAMED_NAMES: Mapping[str, Mapping[str, str]] = {
    "antalate_lcm": {"Autopilot": "VehicleAdapter", "AutopilotState": "VehicleState", "Bus": "Buses"},
    "antalate_lcm.vehicles": {
        "Autopilot": "VehicleAdapter",
        "AutopilotState": "VehicleState",
        "UnknownAutopilotError": "UnknownAdapterError",
        "available_autopilots": "available_adapters",
        "load_autopilot": "load_adapter",
    },
    "antalate_lcm.base.errors": {"UnknownAutopilotError": "UnknownAdapterError"},
    "antalate_lcm.agent.plan": {"AutopilotPlan": "AdapterPlan", "plan_autopilot": "plan_adapter"},
    "antalate_lcm.agent.hlc.node": {"make_autopilot": "make_adapter"},
    "antalate_lcm.vehicles.base": {"Autopilot": "VehicleAdapter", "AutopilotState": "VehicleState"},
    **{  # each adapter package, and its ``adapter`` module, had its class as ``<Package>Autopilot``
        f"antalate_lcm.vehicles.{package}{module}": {
            f"{package.capitalize()}Autopilot": f"{package.capitalize()}Adapter"
        }
        for package in _ADAPTER_PACKAGES
        for module in ("", ".adapter")
    },
    "antalate_lcm.cli": {"commands": "subcommands"},
    "antalate_lcm.core.bus": {"Bus": "Buses"},
    "antalate_lcm.runtime.clock_client": {
        "ClockLink": "ClockClient",
        "SimulatedBus": "SimulatedBuses",
        "SocketLink": "SocketClockClient",
    },
    "antalate_lcm.runtime.time_coordinator": {
        "ClockLink": "ClockClient",
        "LocalLink": "LocalClockClient",
        "SimulatedBus": "SimulatedBuses",
        "SocketLink": "SocketClockClient",
    },
    "operator_tui.board": {"SwarmModel": "SwarmBoard"},
    "operator_tui.web": {"ConsoleLink": "BrowserTab"},
}


def moved_module(old: str) -> Callable[[str], Any]:
    """Warns that ``old`` is deprecated, naming its new module (`MOVED_MODULES`) so the fix is in the
    message, and returns the module ``__getattr__`` for ``old``: names a star import skips (private ones,
    ``__all__``-less extras) still resolve to the very objects of the new module. Called from the shim's
    body, so the warning points at whoever imported the shim (importlib's own frames are skipped by
    :mod:`warnings`)."""
    new = MOVED_MODULES[old]
    warnings.warn(
        f"{old} is deprecated: import {new} (the old name goes in the next release)",
        DeprecationWarning,
        stacklevel=3,
    )
    target = importlib.import_module(new)

    def __getattr__(name: str) -> Any:
        return getattr(target, name)

    return __getattr__


def renamed_names(module: str, otherwise: Callable[[str], Any] | None = None) -> Callable[[str], Any]:
    """The module ``__getattr__`` that keeps ``module``'s renamed names (`RENAMED_NAMES`) working one
    release: each use warns, naming the new name, and gets the very object the new name is bound to.
    Any other name goes to ``otherwise`` (a package's lazy exports), or is missing. Set only where mypy
    does not look (``if not TYPE_CHECKING``), so nothing in the project itself can use an old name."""
    renamed = RENAMED_NAMES[module]

    def __getattr__(name: str) -> Any:
        new = renamed.get(name)
        if new is None:
            if otherwise is not None:
                return otherwise(name)
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(
            f"{module}.{name} is deprecated: use {module}.{new} (the old name goes in the next release)",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(sys.modules[module], new)

    return __getattr__


class renamed_attribute:
    """The class attribute that keeps an instance attribute's old name working one release
    (``autopilot = renamed_attribute("adapter")`` in the class body): reading or setting it warns,
    naming the new attribute, and goes to the new one, so both names are always the same object.
    Set only where mypy does not look (``if not TYPE_CHECKING``), like `renamed_names`' old names.
    A descriptor, not a ``property`` per name, so the warning's words are the same as the modules'.
    It works beside ``__slots__``: it is a class attribute, the value lives in the new name's slot."""

    def __init__(self, new: str) -> None:
        self._new = new
        self._old = new  # replaced by __set_name__ with the name the class binds it to
        self._owner = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self._old, self._owner = name, f"{owner.__module__}.{owner.__qualname__}"

    def _warn(self) -> None:
        warnings.warn(
            f"{self._owner}.{self._old} is deprecated: use {self._owner}.{self._new} "
            "(the old name goes in the next release)",
            DeprecationWarning,
            stacklevel=3,
        )

    def __get__(self, instance: object | None, owner: type | None = None) -> Any:
        if instance is None:
            return self
        self._warn()
        return getattr(instance, self._new)

    def __set__(self, instance: object, value: Any) -> None:
        self._warn()
        setattr(instance, self._new, value)
