"""The one mechanism behind the old names of moved modules, renamed names and renamed attributes (issue
#26, docs/architecture.md, "Deprecated names"): every shim warns the same way and resolves what its star
import left out the same way, so removing them next release is deleting files and lines, and no shim can
drift from the others."""

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
