"""Vehicle adapter contract and adapter registry.

Adapters are found by name in the entry-point group ``antalate.autopilots`` (so third-party packages
can add vehicles without touching this code) or given directly as ``"package.module:ClassName"``.
Only the chosen adapter's module is imported: a missing optional library (djitellopy, pymavlink)
only matters for the adapter that needs it. Lookup goes through `antalate_lcm.base.plugins`, the one
loader shared with behaviors, so both kinds of plugin fail the same way.
"""

from __future__ import annotations

import inspect
from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.errors import PluginNotFound
from antalate_lcm.base.errors import UnknownAdapterError as UnknownAdapterError
from antalate_lcm.base.plugins import AUTOPILOTS, group_entry_points, load_plugin
from antalate_lcm.vehicles.base import AutopilotError, FlightMode, Frame, VehicleAdapter, VehicleState

ENTRY_POINT_GROUP = AUTOPILOTS

__all__ = [
    "ENTRY_POINT_GROUP",
    "VehicleAdapter",
    "AutopilotError",
    "VehicleState",
    "FlightMode",
    "Frame",
    "UnknownAdapterError",
    "available_adapters",
    "load_adapter",
]


def available_adapters() -> dict[str, str]:
    """Registered adapter names mapped to their ``module:Class`` targets, sorted by name."""
    return dict(sorted((ep.name, ep.value) for ep in group_entry_points(ENTRY_POINT_GROUP)))


def load_adapter(name: str) -> type[VehicleAdapter]:
    """The adapter class for `name` (a registered name or ``module:Class``).

    Raises `UnknownAdapterError` -- whatever went wrong: an unknown or malformed name, a module
    that does not import, a class that is not an `VehicleAdapter` -- with one line that lists the
    installed adapters, so a config typo is a one-line fix and never a traceback.
    """
    installed = available_adapters()
    expected = (
        f"expected an installed adapter ({', '.join(installed) or 'none'}) or 'package.module:Class' "
        "naming an VehicleAdapter subclass"
    )
    if ":" not in name and name not in installed:
        raise UnknownAdapterError(f"{expected}; there is no adapter {name!r}")
    try:
        cls = load_plugin(ENTRY_POINT_GROUP, name, VehicleAdapter)
    except PluginNotFound as exc:
        raise UnknownAdapterError(f"{expected}; {exc}") from None
    except Exception as exc:  # noqa: BLE001 - an entry point's module may fail in any way
        raise UnknownAdapterError(f"{expected}; {name!r} failed to load: {exc!r}") from None
    assert issubclass(cls, VehicleAdapter)  # checked by load_plugin; narrows the type
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(getattr(cls, "__abstractmethods__", ())))
        raise UnknownAdapterError(f"{expected}; {name!r} is abstract (it lacks {missing})")
    return cls


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
