"""Deprecated: import from ``tests.harness.jsonl``. Where tests imported these names from before
tests/harness/ gathered the helpers; they still work for one release (a behavior package's tests may
have copied the old path from docs/behaviors.md), with a DeprecationWarning that names the new place."""

import warnings

from tests.harness.jsonl import JsonLinesProcess as JsonLinesProcess

warnings.warn("tests.jsonl is deprecated: import from tests.harness.jsonl", DeprecationWarning, stacklevel=2)
