"""The command line is one table (docs/architecture.md, "The command line"): every subcommand is a row of
``antalate_lcm.cli.subcommands()``, its arguments declared beside its handler, and no module hooks a
subcommand or edits a parser another built (as the web console once did to ``tui``)."""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

from antalate_lcm.cli import build_parser, subcommands

REPO = Path(__file__).resolve().parent.parent.parent
PACKAGES = ("antalate_lcm", "operator_tui", "behaviors")
CLI = REPO / "antalate_lcm" / "cli.py"


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction[argparse.ArgumentParser]:
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action


def test_the_parser_is_the_table_in_its_order() -> None:
    rows = subcommands()
    names = [row.name for row in rows]
    assert len(set(names)) == len(names)
    sub = _subparsers(build_parser())
    assert list(sub.choices) == names
    assert [a.help for a in sub._choices_actions] == [row.help for row in rows]
    for row in rows:
        assert sub.choices[row.name].get_default("func") is row.run, row.name


def test_each_command_declares_its_arguments_beside_its_handler() -> None:
    misplaced = {
        row.name: (row.arguments.__module__, row.run.__module__)
        for row in subcommands()
        if row.arguments is not None and row.arguments.__module__ != row.run.__module__
    }
    assert misplaced == {}


def _hooks(source: str, where: str) -> list[str]:
    """Calls that add a subcommand, hook a handler or reach into a built parser's subcommands."""
    found = []
    for node in ast.walk(ast.parse(source, where)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            hook = node.func.attr == "set_defaults" and any(k.arg == "func" for k in node.keywords)
            if hook or node.func.attr in ("add_subparsers", "add_parser"):
                found.append(f"{where}:{node.lineno}: .{node.func.attr}(...)")
        elif (
            isinstance(node, ast.Attribute)
            and node.attr in ("choices", "_choices_actions")
            and isinstance(node.value, ast.Name)
            and node.value.id == "sub"
        ):
            found.append(f"{where}:{node.lineno}: sub.{node.attr}")
    return found


def test_no_module_but_the_table_adds_or_edits_a_subcommand() -> None:
    hooks = [
        hook
        for package in PACKAGES
        for path in sorted((REPO / package).rglob("*.py"))
        for hook in _hooks(path.read_text(), str(path.relative_to(REPO)))
    ]
    # ``antalate new KIND``: the one nested choice, declared by ``new``'s own arguments function
    nested = [h for h in hooks if h.startswith("antalate_lcm/runtime/scaffold.py")]
    assert len(nested) == 2, nested  # kinds = p.add_subparsers(...); kinds.add_parser("behavior", ...)
    assert [h for h in hooks if h not in nested and not h.startswith("antalate_lcm/cli.py")] == []


def test_the_hook_finder_sees_the_old_way() -> None:
    """The check above would have caught the web console editing ``tui`` after it was built."""
    old = (
        "def register(sub):\n"
        "    p = sub.choices['tui']\n"
        "    p.add_argument('--web')\n"
        "    p.set_defaults(func=print)\n"
    )
    assert sorted(h.split(": ", 1)[1] for h in _hooks(old, "web.py")) == [".set_defaults(...)", "sub.choices"]
