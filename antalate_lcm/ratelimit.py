"""Deprecated name of :mod:`antalate_lcm.base.ratelimit`, where issue #26 moved it: behavior authors and the
docs imported it, so it keeps working, with a warning, for one release (:mod:`antalate_lcm.base.deprecation`).
"""

from antalate_lcm.base.deprecation import moved_module
from antalate_lcm.base.ratelimit import *  # noqa: F403 - the old name offers what the new one does

__getattr__ = moved_module(__name__)
