"""``antalate types --lang LANG --out DIR``: message bindings for nodes written in other languages.

Talking to C, C++, Java and Go nodes is why one picks LCM; an installed antalate carries its ``.lcm``
files (``antalate_lcm/lcmtypes/``) and the ``lcm-gen`` of the lcm wheel, so a user gets bindings
whose fingerprints match the Python nodes exactly, without the source tree. ``--lang lcm`` copies
the definitions themselves, for a build that runs its own ``lcm-gen``.

Go is the exception: lcm-gen 1.5.3's Go emitter crashes on ``header_t.mac`` (a variable-length
array, in every message), so ``tools.golang`` writes the Go lcm-gen would have written (same API, wire
format and fingerprints; ``tests/tools/test_types_go.py`` compares the two).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import time
from pathlib import Path

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.tools import codegen, golang

# lcm-gen's switches per language: emit, then where the files go (C: sources and headers apart is
# lcm-gen's default too, one folder is what a small node's Makefile wants).
_LCM_GEN_ARGS: dict[str, list[str]] = {
    "c": ["--c", "--c-cpath", "{out}", "--c-hpath", "{out}"],
    "cpp": ["--cpp", "--cpp-std", "c++11", "--cpp-hpath", "{out}"],
    "java": ["--java", "--jpath", "{out}"],
    "python": ["--python", "--ppath", "{out}"],
    "lua": ["--lua", "--lpath", "{out}"],
    "csharp": ["--csharp", "--csharp-path", "{out}"],
}
LANGUAGES: tuple[str, ...] = (*_LCM_GEN_ARGS, "go", "lcm")


def lcm_gen_command(lang: str, out: Path, files: list[Path]) -> list[str]:
    """The lcm-gen command line that writes ``lang`` bindings of ``files`` into ``out``."""
    if lang not in _LCM_GEN_ARGS:
        raise AntalateError(f"unknown language {lang!r}: one of {', '.join(LANGUAGES)}")
    args = [a.format(out=out) for a in _LCM_GEN_ARGS[lang]]
    return [codegen.lcm_tool("lcm-gen"), *args, *map(str, files)]


def write_types(lang: str, out: Path) -> list[Path]:
    """Write the bindings (or the ``.lcm`` files) into ``out``; returns the files written, sorted."""
    files = codegen.lcm_files()
    if not files:
        raise AntalateError(
            f"no .lcm files in {codegen.LCMTYPES_DIR}: this antalate was installed without its message "
            "definitions (rebuild the wheel from a checkout)"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise AntalateError(f"cannot create {out}: {exc.strerror or exc}") from None
    if lang == "lcm":
        for src in files:
            shutil.copy2(src, out / src.name)
        return sorted(out / src.name for src in files)
    if lang == "go":
        return golang.write_go(files, out)
    try:
        cmd = lcm_gen_command(lang, out, files)
    except FileNotFoundError as exc:
        raise AntalateError(str(exc)) from None
    started = time.time_ns() - 2_000_000_000  # coarse file-system timestamps
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        said = (proc.stderr.strip() or proc.stdout.strip() or "no message").splitlines()[-1]
        raise AntalateError(f"lcm-gen failed for --lang {lang} (exit {proc.returncode}: {said})")
    # lcm-gen does not say what it wrote: every file it (re)wrote just now
    return sorted(p for p in out.rglob("*") if p.is_file() and p.stat().st_mtime_ns >= started)


def run(lang: str, out: str) -> int:
    written = write_types(lang, Path(out))
    print(f"antalate types: {len(written)} {lang} files in {out}")
    return 0


def types_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--lang", required=True, choices=LANGUAGES, help="target language, or lcm for the .lcm files"
    )
    p.add_argument("--out", required=True, help="folder to write into (created if missing)")


def cmd_types(args: argparse.Namespace) -> int:
    return run(args.lang, args.out)
