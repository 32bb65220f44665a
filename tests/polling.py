"""Deprecated: import from ``tests.harness.polling``. Where tests imported these names from before
tests/harness/ gathered the helpers; they still work for one release (a behavior package's tests may
have copied the old path from docs/behaviors.md), with a DeprecationWarning that names the new place."""

import warnings

from tests.harness.polling import wait_for as wait_for

warnings.warn(
    "tests.polling is deprecated: import from tests.harness.polling", DeprecationWarning, stacklevel=2
)
