"""The fenced code blocks of the docs, and the checks that keep them true (tests/architecture/test_doc_snippets.py).

A block is the text between two fences, with its language and the HTML comment (if any) on the
line just above its opening fence: ``<!-- file: PATH -->`` says "this block is the file PATH",
``<!-- check: why -->`` says "these commands are checked, not run" (they run until Ctrl-C, or on
several hosts). Commands that are only checked are parsed by antalate's own parser, and what they
name is checked the way the command itself would before doing anything: a config is loaded and
validated with its plugins, ``antalate run`` runs its whole pre-flight check (``prepare``).

Run as ``python -m tests.architecture.doc_snippets antalate ARGS...`` it checks one command line in the current
folder (the tutorial's test uses it for its ``check`` blocks, inside the tutorial's folder).
"""

from __future__ import annotations

import re
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from tests import REPO

_FENCE = re.compile(r"^(?P<indent>[ \t]*)```(?P<lang>[\w+-]*)\s*$")
_NOTE = re.compile(r"^\s*<!--\s*(?P<note>.*?)\s*-->\s*$")
#: antalate subcommands whose first positional argument is an agent config.
_CONFIG_COMMANDS = {"agent", "mc", "hlc", "bma", "osc", "tui", "spy", "log"}


@dataclass(frozen=True)
class Block:
    doc: str
    line: int  # of the opening fence, 1-based
    lang: str
    text: str
    note: str

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"

    @property
    def file(self) -> str | None:
        return self.note.removeprefix("file:").strip() if self.note.startswith("file:") else None


def blocks(doc: str) -> list[Block]:
    """Every fenced block of ``doc`` (a path relative to the repository), in order."""
    lines = (REPO / doc).read_text(encoding="utf-8").splitlines()
    out: list[Block] = []
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, start = len(m["indent"]), i
        body: list[str] = []
        i += 1
        while i < len(lines) and lines[i].strip() != "```":
            line = lines[i]
            body.append(line[indent:] if not line[:indent].strip() else line.lstrip())
            i += 1
        if i == len(lines):
            raise AssertionError(f"{doc}:{start + 1}: a code block is never closed")
        prev = lines[start - 1] if start else ""
        note = _NOTE.match(prev)
        out.append(Block(doc, start + 1, m["lang"], "\n".join(body) + "\n", note["note"] if note else ""))
        i += 1
    return out


def commands(text: str) -> list[list[str]]:
    """The command lines of a shell block: continuations joined, comments dropped, split at
    ``&&``, ``;`` and ``|``, environment assignments and ``sudo``/``xvfb-run -a`` wrappers removed."""
    out: list[list[str]] = []
    for line in text.replace("\\\n", " ").splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
        lexer.whitespace_split = True
        lexer.commenters = "#"
        words: list[str] = []
        for word in [*lexer, ";"]:
            if word in {";", "&&", "||", "|", "&"}:
                while words and ("=" in words[0] and not words[0].startswith("-") or words[0] == "sudo"):
                    words.pop(0)
                if words[:2] == ["xvfb-run", "-a"]:
                    words = words[2:]
                if words:
                    out.append(words)
                words = []
            else:
                words.append(word)
    return out


def is_antalate(words: list[str]) -> bool:
    return bool(words) and (words[0] == "antalate" or words[0].endswith("/antalate"))


def check_antalate(args: list[str], cwd: Path, *, parse_only: bool = False) -> None:
    """``antalate ARGS`` would start: the parser takes it, and (unless ``parse_only``) its config
    or, for ``run``, its whole experiment passes the checks the command makes before anything starts."""
    import contextlib
    import io

    from antalate_lcm.cli import build_parser

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            ns = build_parser().parse_args(args)
    except SystemExit as exc:
        raise AssertionError(f"antalate {shlex.join(args)}: {err.getvalue().strip()}") from exc
    if parse_only:
        return
    if ns.command == "run":
        from antalate_lcm.runtime.experiment import Experiment, prepare
        from antalate_lcm.runtime.script import load_script

        script = load_script(str(cwd / ns.script)) if ns.script else None
        with tempfile.TemporaryDirectory() as tmp:
            prepare(
                Experiment(
                    config_path=str(cwd / ns.config),
                    agents=ns.agents,
                    processes=ns.processes,
                    spacing=ns.spacing,
                    script=script,
                    output=str(Path(tmp) / "flight.lcm"),
                    bus=ns.bus,
                )
            )
        return
    if ns.command == "sweep":  # the spec, and every run it makes, as `antalate sweep` checks them
        from antalate_lcm.runtime.sweep import load_sweep

        load_sweep(cwd / ns.spec)
        return
    config = getattr(ns, "config", None)
    if ns.command in _CONFIG_COMMANDS and isinstance(config, str) and config.endswith(".toml"):
        from antalate_lcm.core.config import load_config
        from antalate_lcm.runtime.agent import validate

        validate(load_config(str(cwd / config)))


if __name__ == "__main__":
    if sys.argv[1:2] != ["antalate"]:
        sys.exit("usage: python -m tests.architecture.doc_snippets antalate ARGS...")
    check_antalate(sys.argv[2:], Path.cwd())
    print(f"checked: antalate {shlex.join(sys.argv[2:])}")
