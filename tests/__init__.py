"""antalate test suite."""

from pathlib import Path

#: The checkout the tests run from (its examples, docs, tools and the packages under test).
REPO = Path(__file__).resolve().parent.parent
