"""Load plugins by entry-point name or ``module:Class`` — the one way antalate finds extensions.

Used for behaviors (group ``antalate.behaviors``) and vehicle adapters (``antalate.autopilots``).
"""

from __future__ import annotations

import importlib
import re
import sys
from importlib.metadata import EntryPoint, entry_points

from antalate_lcm.base.errors import PluginNotFound

BEHAVIORS = "antalate.behaviors"
AUTOPILOTS = "antalate.autopilots"

#: ``package.module`` (absolute: there is no package to be relative to) and ``ClassName``.
_MODULE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
_CLASS = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


#: (group, sys.path) -> its entry points: scanning every installed distribution's metadata takes
#: ~6 ms, and ``antalate agent --agents 1000`` looked its adapter up 2,000 times (12 s before the
#: first agent started). A changed sys.path (a plugin installed into it) is a new key.
_ENTRY_POINTS: dict[tuple[str, tuple[str, ...]], tuple[EntryPoint, ...]] = {}


def group_entry_points(group: str) -> tuple[EntryPoint, ...]:
    """The entry points registered in ``group``, for this sys.path (read once)."""
    key = (group, tuple(sys.path))
    found = _ENTRY_POINTS.get(key)
    if found is None:
        found = _ENTRY_POINTS[key] = tuple(entry_points(group=group))
    return found


def available(group: str) -> list[str]:
    return sorted(ep.name for ep in group_entry_points(group))


def load_plugin(group: str, name: str, base: type) -> type:
    """The ``base`` subclass registered as ``name`` in ``group``, or named ``module:Class``.

    Raises :class:`PluginNotFound` listing what is available, so a typo in a config is a one-line fix.
    ``base`` is a plain ``type`` (an abstract class cannot be a ``type[T]`` to mypy): callers narrow
    the result with ``assert issubclass(cls, base)``.
    """
    if ":" in name:
        module_name, _, attr = name.partition(":")
        if not (_MODULE.fullmatch(module_name) and _CLASS.fullmatch(attr)):
            raise PluginNotFound(
                f"cannot load {name!r}: expected 'package.module:ClassName' (an absolute module path)"
            )
        try:
            obj = getattr(importlib.import_module(module_name), attr)
        except (ImportError, AttributeError) as exc:
            raise PluginNotFound(f"cannot load {name!r}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a module that breaks on import is a config error too
            raise PluginNotFound(f"cannot load {name!r}: importing {module_name} failed: {exc!r}") from None
    else:
        matches = [ep for ep in group_entry_points(group) if ep.name == name]
        if not matches:
            raise PluginNotFound(
                f"no plugin {name!r} in {group}; available: {', '.join(available(group)) or 'none'} "
                "(or give 'module:Class')"
            )
        try:
            obj = matches[0].load()
        except Exception as exc:  # noqa: BLE001 - a broken plugin must not look like a missing one
            raise PluginNotFound(f"plugin {name!r} in {group} failed to import: {exc!r}") from None
    if not (isinstance(obj, type) and issubclass(obj, base)):
        raise PluginNotFound(f"{name!r} is not a subclass of {base.__module__}.{base.__qualname__}")
    return obj
