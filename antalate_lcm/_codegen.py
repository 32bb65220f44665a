"""Generate the Python message modules from ``lcmtypes/`` with the ``lcm-gen`` that ships in the lcm wheel.

The generated modules are committed (so a plain ``pip install`` needs no code generator) and
``tests/test_codegen.py`` fails when they are stale against ``lcmtypes/`` or were edited by hand.
Run ``python -m antalate_lcm._codegen`` (or ``make gen``) after editing a ``.lcm`` file.

``lcmtypes/`` at the repository root stays the source of truth; ``make gen`` also copies the ``.lcm``
files into ``antalate_lcm/lcmtypes/`` so they travel inside the wheel: an installed antalate has no
source tree, and ``antalate spy`` / ``antalate types`` still need the definitions.
"""

from __future__ import annotations

import filecmp
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
SOURCE_LCMTYPES_DIR = REPO_ROOT / "lcmtypes"
PACKAGED_LCMTYPES_DIR = Path(__file__).resolve().parent / "lcmtypes"


def _lcmtypes_dir() -> Path:
    """The source tree's ``lcmtypes/`` in a checkout (an edit counts before ``make gen``), else the
    copy installed with the package."""
    if SOURCE_LCMTYPES_DIR.is_dir() and (REPO_ROOT / "pyproject.toml").is_file():
        return SOURCE_LCMTYPES_DIR
    return PACKAGED_LCMTYPES_DIR


LCMTYPES_DIR = _lcmtypes_dir()
MSGS_DIR = Path(__file__).resolve().parent / "msgs"
_MSGS_SUBPATH = Path("antalate_lcm") / "msgs"


def lcm_tool(name: str) -> str:
    """Path of an LCM command-line tool (``lcm-gen``, ``lcm-spy``, ...), preferring this interpreter's."""
    candidates = [Path(sysconfig.get_path("scripts")) / name, Path(sys.executable).parent / name]
    for candidate in candidates:
        if candidate.exists():
            return str(candidate)
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"{name} not found: install the 'lcm' Python package (pip install lcm)")
    return found


def lcm_files() -> list[Path]:
    return sorted(LCMTYPES_DIR.glob("*.lcm"))


def stale_packaged_types() -> list[str]:
    """Names of ``.lcm`` files whose packaged copy is missing, extra or differs from ``lcmtypes/``."""
    source = {p.name: p for p in SOURCE_LCMTYPES_DIR.glob("*.lcm")}
    packaged = {p.name: p for p in PACKAGED_LCMTYPES_DIR.glob("*.lcm")}
    problems = sorted(set(source) ^ set(packaged))
    for name in sorted(set(source) & set(packaged)):
        if not filecmp.cmp(source[name], packaged[name], shallow=False):
            problems.append(name)
    return problems


def copy_packaged_types() -> None:
    """Make ``antalate_lcm/lcmtypes/`` an exact copy of ``lcmtypes/`` (what the wheel ships)."""
    PACKAGED_LCMTYPES_DIR.mkdir(parents=True, exist_ok=True)
    for old in PACKAGED_LCMTYPES_DIR.glob("*.lcm"):
        old.unlink()
    for src in SOURCE_LCMTYPES_DIR.glob("*.lcm"):
        shutil.copy2(src, PACKAGED_LCMTYPES_DIR / src.name)


def generate_python(out_dir: Path) -> Path:
    """Run lcm-gen for Python into ``out_dir`` and return the generated ``msgs`` package folder."""
    subprocess.run(
        [lcm_tool("lcm-gen"), "--python", "--ppath", str(out_dir), *map(str, lcm_files())],
        check=True,
        capture_output=True,
        text=True,
    )
    return out_dir / _MSGS_SUBPATH


def generate_java(out_dir: Path) -> Path:
    """Run lcm-gen for Java into ``out_dir`` (used by ``antalate spy`` and the cross-language test)."""
    subprocess.run(
        [lcm_tool("lcm-gen"), "--java", "--jpath", str(out_dir), *map(str, lcm_files())],
        check=True,
        capture_output=True,
        text=True,
    )
    return out_dir


def stale_files() -> list[str]:
    """Names of generated files that differ from a fresh generation (empty when up to date)."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = generate_python(Path(tmp))
        fresh_names = {p.name for p in fresh.glob("*.py")}
        committed = {p.name for p in MSGS_DIR.glob("*.py")}
        problems = sorted(fresh_names ^ committed)
        for name in sorted(fresh_names & committed):
            if not filecmp.cmp(fresh / name, MSGS_DIR / name, shallow=False):
                problems.append(name)
        return problems


def regenerate() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        fresh = generate_python(Path(tmp))
        for old in MSGS_DIR.glob("*.py"):
            old.unlink()
        MSGS_DIR.mkdir(parents=True, exist_ok=True)
        for new in fresh.glob("*.py"):
            shutil.copy2(new, MSGS_DIR / new.name)


if __name__ == "__main__":
    regenerate()
    copy_packaged_types()
    print(f"generated {len(list(MSGS_DIR.glob('*.py')))} modules in {MSGS_DIR}")
