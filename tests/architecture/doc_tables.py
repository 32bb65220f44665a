"""The tables of docs/architecture.md that tests hold the code to (test_file_size.py's "Files over 500 lines",
test_deprecated_names.py's "Deprecated names"): one reader, so the tests cannot read a table two ways."""

from __future__ import annotations

import re

_ROW = re.compile(r"^\| `([^`]+)` \|(.*)\|\s*$", re.M)


def section_table(doc: str, heading: str) -> dict[str, str]:
    """The rows of the table in ``doc``'s section ``heading`` (a whole heading line, ``## Name``, up to the
    next ``## `` heading) whose first cell is one code span: that span -> the rest of the row, stripped.
    A row whose first cell says more (``Class.attr`` (module), an attribute) is not one of them."""
    start = doc.index(heading)
    end = doc.find("\n## ", start + len(heading))
    section = doc[start : end if end >= 0 else len(doc)]
    return {m.group(1): m.group(2).strip() for m in _ROW.finditer(section)}
