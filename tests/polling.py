"""Deprecated: import from ``tests.harness.polling``. docs/behaviors.md showed this path (``from
tests.polling import wait_for``), so a behavior package's tests may have copied it; the name keeps working
for one release, with a DeprecationWarning that names the new place."""

import warnings

from tests.harness.polling import wait_for as wait_for

warnings.warn(
    "tests.polling is deprecated: import from tests.harness.polling", DeprecationWarning, stacklevel=2
)
