"""Deprecated name of :mod:`operator_tui.board`, where issue #26's vocabulary renamed it (docs/architecture.md,
"Vocabulary"): import that. It keeps working, with a warning, until the next release removes it."""

from antalate_lcm.base.deprecation import moved_module
from operator_tui.board import *  # noqa: F403 - the old name offers what the new one does

__getattr__ = moved_module(__name__)
