"""Deprecated name of :mod:`operator_tui.node`, where issue #26's vocabulary renamed it (docs/architecture.md,
"Vocabulary"): import that. It keeps working, with a warning, until the next release removes it."""

from __future__ import annotations

import warnings
from typing import Any

from operator_tui import node as _moved
from operator_tui.node import *  # noqa: F403 - the old name offers what the new one does

warnings.warn(
    "operator_tui.link is deprecated: import operator_tui.node (the old name goes in the next release)",
    DeprecationWarning,
    stacklevel=2,
)


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
