"""The one mechanism behind the old names of moved modules (issue #26, docs/architecture.md, "Deprecated
names"): every shim warns the same way and resolves what its star import left out the same way, so
removing them next release is deleting files, and no shim can drift from the others."""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable, Mapping
from typing import Any


def moved_module(old: str, new: str) -> Callable[[str], Any]:
    """Warns that ``old`` is deprecated, naming ``new`` so the fix is in the message, and returns the module
    ``__getattr__`` for ``old``: names a star import skips (private ones, ``__all__``-less extras) still
    resolve to the very objects of ``new``. Called from the shim's body, so the warning points at whoever
    imported the shim (importlib's own frames are skipped by :mod:`warnings`)."""
    warnings.warn(
        f"{old} is deprecated: import {new} (the old name goes in the next release)",
        DeprecationWarning,
        stacklevel=3,
    )
    target = importlib.import_module(new)

    def __getattr__(name: str) -> Any:
        return getattr(target, name)

    return __getattr__


def renamed_names(module: str, renamed: Mapping[str, str]) -> Callable[[str], Any]:
    """The module ``__getattr__`` that keeps ``module``'s renamed names (old -> new, issue #26's
    vocabulary) working one release: each use warns, naming the new name, and gets the very object
    the new name is bound to. Set only where mypy does not look (``if not TYPE_CHECKING``), so
    nothing in the project itself can use an old name."""

    def __getattr__(name: str) -> Any:
        new = renamed.get(name)
        if new is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(
            f"{module}.{name} is deprecated: use {module}.{new} (the old name goes in the next release)",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(sys.modules[module], new)

    return __getattr__
