"""Tables of refusals (a bad config, script, fault or sweep spec; the key its one-line error names; a
phrase of that error) kept as TOML files beside the tests that read them.

Their inputs are TOML text: written as TOML they read as a user writes them, without the ``\\n`` escapes
of a Python string, and a new case is three lines of data, not code. Each ``[[case]]`` holds the
arguments of one test in the order of the test's parametrize names; the test ids are the values, as
they were when the tables were Python literals.
"""

from __future__ import annotations

import sys
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

from tests import REPO

TESTS = REPO / "tests"


def cases(path: str) -> list[tuple[Any, ...]]:
    """The ``[[case]]`` rows of ``tests/<path>``, each the tuple of its values in the file's order."""
    rows = tomllib.loads((TESTS / path).read_text())["case"]
    keys = list(rows[0])
    for i, row in enumerate(rows):
        assert list(row) == keys, f"{path}: case {i} has keys {list(row)}, the first has {keys}"
    return [tuple(row.values()) for row in rows]
