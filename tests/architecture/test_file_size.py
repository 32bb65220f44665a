"""No product file over 500 lines unless docs/architecture.md ("Files over 500 lines") says why (issue 26).

The section is the one place: its table names the files that stay whole with their reason; this
test reads it, so the list cannot drift from the code either way (a file that grows past the limit
unlisted fails, and so does a listed file that was split).
"""

from __future__ import annotations

from tests import REPO
from tests.architecture.doc_tables import section_table

#: Lines a product file may have (``wc -l``).
LIMIT = 500
PACKAGES = ("antalate_lcm", "operator_tui", "behaviors")
#: lcm-gen's output (``make gen``), exempt by issue 26.
GENERATED = "antalate_lcm/msgs/"
DOC = REPO / "docs" / "architecture.md"
SECTION = "## Files over 500 lines"


def listed(doc: str) -> dict[str, str]:
    """The section's table (file -> why it stays whole), from ``doc``'s text."""
    return section_table(doc, SECTION)


def line_counts() -> dict[str, int]:
    """Every product module (generated messages left out) and its number of lines."""
    counts = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if not rel.startswith(GENERATED):
                counts[rel] = len(path.read_text(encoding="utf-8").splitlines())
    return counts


def test_no_product_file_is_over_the_limit_unless_the_doc_says_why() -> None:
    whole = listed(DOC.read_text(encoding="utf-8"))
    over = {rel: n for rel, n in line_counts().items() if n > LIMIT}
    unexplained = {rel: n for rel, n in over.items() if rel not in whole}
    assert unexplained == {}, (
        f"over {LIMIT} lines: split by responsibility, or say why it stays whole in "
        f"docs/architecture.md, {SECTION!r}"
    )
    assert all(whole.values()), "every file that stays whole has its reason"


def test_every_listed_file_is_still_over_the_limit() -> None:
    """A line of the section goes once its file is split (or gone): the list never holds stale names."""
    whole = listed(DOC.read_text(encoding="utf-8"))
    counts = line_counts()
    stale = [rel for rel in whole if counts.get(rel, 0) <= LIMIT]
    assert stale == []


def test_the_section_is_read_as_written() -> None:
    """The reader finds the table's files and reasons, and nothing of the sections around them."""
    doc = (
        "## Before\n\n| `antalate_lcm/a.py` | not this one |\n\n"
        f"{SECTION}\n\nText.\n\n| file | why it stays whole |\n|---|---|\n"
        "| `antalate_lcm/b.py` | a table read top to bottom |\n| `operator_tui/c.py` |  |\n\n"
        "## After\n\n| `antalate_lcm/f.py` | nor this one |\n"
    )
    assert listed(doc) == {"antalate_lcm/b.py": "a table read top to bottom", "operator_tui/c.py": ""}
    real_whole = listed(DOC.read_text(encoding="utf-8"))
    assert real_whole  # the real section parses to something (or the rule is void)
