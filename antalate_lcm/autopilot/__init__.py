"""Deprecated name of :mod:`antalate_lcm.vehicles`, where issue #26's vocabulary renamed it (docs/architecture.md,
"Vocabulary"): import that. It keeps working, with a warning, until the next release removes it,
submodules included: ``antalate_lcm.autopilot.X`` is the very module ``antalate_lcm.vehicles.X`` (so a config's
``"antalate_lcm.autopilot.sim:SimAutopilot"`` still loads the same class)."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from collections.abc import Sequence
from types import ModuleType
from typing import Any

from antalate_lcm import vehicles as _moved
from antalate_lcm.base.deprecation import MOVED_MODULES
from antalate_lcm.vehicles import *  # noqa: F403 - the old name offers what the new one does

_OLD = __name__
_NEW = MOVED_MODULES[_OLD]

warnings.warn(
    f"{_OLD} is deprecated: import {_NEW} (the old name goes in the next release)",
    DeprecationWarning,
    stacklevel=2,
)


class _MovedModule(importlib.abc.Loader):
    """Loads an old submodule name as the module already imported under its new name."""

    def __init__(self, new: str) -> None:
        self._new = new
        self._spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(self._new)
        self._spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__ = self._spec  # the import system set the old name's; the module keeps its own


class _OldSubmodules(importlib.abc.MetaPathFinder):
    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if not fullname.startswith(_OLD + "."):
            return None
        new = _NEW + fullname[len(_OLD) :]
        warnings.warn(
            f"{fullname} is deprecated: import {new} (the old name goes in the next release)",
            DeprecationWarning,
            stacklevel=2,
        )
        return importlib.machinery.ModuleSpec(fullname, _MovedModule(new))


if not any(type(f).__name__ == "_OldSubmodules" and getattr(f, "old", None) == _OLD for f in sys.meta_path):
    _finder = _OldSubmodules()
    _finder.old = _OLD  # type: ignore[attr-defined]
    sys.meta_path.insert(0, _finder)


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
