"""Load plugins by entry-point name or ``module:Class`` — the one way antalate finds extensions.

Used for behaviors (group ``antalate.behaviors``) and autopilot adapters (``antalate.autopilots``).
"""

from __future__ import annotations

import importlib
import re
from importlib.metadata import entry_points

from antalate_lcm.errors import PluginNotFound

BEHAVIORS = "antalate.behaviors"
AUTOPILOTS = "antalate.autopilots"

#: ``package.module`` (absolute: there is no package to be relative to) and ``ClassName``.
_MODULE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
_CLASS = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def available(group: str) -> list[str]:
    return sorted(ep.name for ep in entry_points(group=group))


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
        matches = [ep for ep in entry_points(group=group) if ep.name == name]
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
