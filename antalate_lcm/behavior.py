"""Deprecated name of :mod:`antalate_lcm.core.behavior`, where issue #26 moved it (its layer folder): import
that. Behavior authors and the docs imported this name, so it keeps working, with a warning, until the
next release removes it."""

from __future__ import annotations

import warnings
from typing import Any

from antalate_lcm.core import behavior as _moved
from antalate_lcm.core.behavior import *  # noqa: F403 - the old name offers what the new one does

warnings.warn(
    "antalate_lcm.behavior is deprecated: import antalate_lcm.core.behavior (the old name goes in the next release)",
    DeprecationWarning,
    stacklevel=2,
)


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
