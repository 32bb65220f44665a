"""Deprecated name of :mod:`antalate_lcm.runtime.cli`, where issue #26's vocabulary renamed it (docs/architecture.md,
"Vocabulary"): import that. It keeps working, with a warning, until the next release removes it."""

from __future__ import annotations

import warnings
from typing import Any

from antalate_lcm.runtime import cli as _moved
from antalate_lcm.runtime.cli import *  # noqa: F403 - the old name offers what the new one does

warnings.warn(
    "antalate_lcm.runtime.commands is deprecated: import antalate_lcm.runtime.cli (the old name goes in the next release)",
    DeprecationWarning,
    stacklevel=2,
)


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
