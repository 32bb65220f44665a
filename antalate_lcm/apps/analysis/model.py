"""Deprecated name of :mod:`antalate_lcm.apps.analysis.records`, where issue #26's vocabulary renamed it (docs/architecture.md,
"Vocabulary"): import that. It keeps working, with a warning, until the next release removes it."""

from antalate_lcm.apps.analysis.records import *  # noqa: F403 - the old name offers what the new one does
from antalate_lcm.base.deprecation import moved_module

__getattr__ = moved_module(__name__)
