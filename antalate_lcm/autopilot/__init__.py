"""Autopilot contract and adapter registry.

Adapters are found by name in the entry-point group ``antalate.autopilots`` (so third-party packages
can add vehicles without touching this code) or given directly as ``"package.module:ClassName"``.
Only the chosen adapter's module is imported: a missing optional library (djitellopy, pymavlink)
only matters for the adapter that needs it.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from antalate_lcm.autopilot.base import Autopilot, AutopilotError, AutopilotState, FlightMode, Frame

ENTRY_POINT_GROUP = "antalate.autopilots"

__all__ = [
    "ENTRY_POINT_GROUP",
    "Autopilot",
    "AutopilotError",
    "AutopilotState",
    "FlightMode",
    "Frame",
    "UnknownAutopilotError",
    "available_autopilots",
    "load_autopilot",
]


class UnknownAutopilotError(LookupError):
    """The configured autopilot name matches no registered adapter, or it cannot be loaded."""


def available_autopilots() -> dict[str, str]:
    """Registered adapter names mapped to their ``module:Class`` targets, sorted by name."""
    found = {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}
    return dict(sorted(found.items()))


def load_autopilot(name: str) -> type[Autopilot]:
    """The adapter class for `name` (a registered name or ``module:Class``).

    Raises `UnknownAutopilotError` naming the available adapters, so a config typo is a one-line fix.
    """
    registered = available_autopilots()
    if name in registered:
        target = registered[name]
    elif ":" in name:
        target = name
    else:
        choices = ", ".join(registered) or "(none registered: is the 'antalate' package installed?)"
        raise UnknownAutopilotError(
            f"unknown autopilot {name!r}; available: {choices}; or give 'package.module:ClassName'"
        )
    module_name, _, attr = target.partition(":")
    try:
        obj: object = importlib.import_module(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise UnknownAutopilotError(f"autopilot {name!r} ({target}) cannot be loaded: {exc}") from exc
    if not (isinstance(obj, type) and issubclass(obj, Autopilot)):
        raise UnknownAutopilotError(f"autopilot {name!r} ({target}) is not an Autopilot subclass")
    return obj
