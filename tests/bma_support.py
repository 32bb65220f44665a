"""Deprecated: import from ``tests.harness.bma``. docs/behaviors.md showed this path (``from
tests.bma_support import harness, make_config`` and ``plugin = "tests.bma_support:ModeSwitcher"``), so a
behavior package's tests may have copied it; the names keep working for one release, the very same
objects, with a DeprecationWarning that names the new place."""

import warnings

from tests.harness.bma import AGENT as AGENT
from tests.harness.bma import Delayed as Delayed
from tests.harness.bma import Harness as Harness
from tests.harness.bma import ModeSwitcher as ModeSwitcher
from tests.harness.bma import Raiser as Raiser
from tests.harness.bma import Recorder as Recorder
from tests.harness.bma import harness as harness
from tests.harness.bma import make_config as make_config

warnings.warn(
    "tests.bma_support is deprecated: import from tests.harness.bma", DeprecationWarning, stacklevel=2
)
