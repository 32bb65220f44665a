"""The tables of docs/architecture.md that tests hold the code to (test_file_size.py's "Files over 500 lines",
test_deprecated_names.py's "Deprecated names"): one reader, so the tests cannot read a table two ways."""

from __future__ import annotations

import re

_ROW = re.compile(r"^\|(.*)\|\s*$", re.M)
_ONE_CODE_SPAN = re.compile(r"`([^`]+)`")


def section_rows(doc: str, heading: str) -> list[list[str]]:
    """The rows of the tables in ``doc``'s section ``heading`` (a whole heading line, ``## Name``, up to the
    next ``## `` heading), each as its cells, stripped; the header and its ``|---|`` line included."""
    start = doc.index(heading)
    end = doc.find("\n## ", start + len(heading))
    section = doc[start : end if end >= 0 else len(doc)]
    return [[cell.strip() for cell in m.group(1).split("|")] for m in _ROW.finditer(section)]


def section_table(doc: str, heading: str) -> dict[str, str]:
    """The rows of `section_rows` whose first cell is one code span: that span -> the rest of the row. A row
    whose first cell says more (```Class.attr`` (`module`), an attribute``) is not one of them."""
    table = {}
    for first, *rest in section_rows(doc, heading):
        if m := _ONE_CODE_SPAN.fullmatch(first):
            table[m.group(1)] = "|".join(rest).strip()
    return table
