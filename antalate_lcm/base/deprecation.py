"""The one mechanism behind the old names of moved modules (issue #26, docs/architecture.md, "Deprecated
names"): every shim warns the same way and resolves what its star import left out the same way, so
removing them next release is deleting files, and no shim can drift from the others."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
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
