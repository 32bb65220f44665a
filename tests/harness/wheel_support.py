"""Build antalate's wheel from the working tree, as a user's ``pip wheel .`` would, for the tests that
install it (a fresh venv, a container image): they test what ships, not the source tree."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from tests import REPO


def source_files() -> list[str]:
    """Tracked and new (not ignored) files: what a fresh clone with this change would hold."""
    proc = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=True,
    )
    return [name for name in proc.stdout.decode().split("\0") if name and (REPO / name).is_file()]


def build_wheel(workdir: Path) -> Path:
    """Copy the tree to ``workdir/src`` (the build writes build/ and *.egg-info, never into the
    shared checkout) and build the wheel into ``workdir/dist``; returns the wheel's path."""
    src, dist = workdir / "src", workdir / "dist"
    for name in source_files():
        target = src / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, target)
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(src)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    wheels = sorted(dist.glob("antalate-*.whl"))
    if proc.returncode != 0 or len(wheels) != 1:
        raise AssertionError(f"pip wheel failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return wheels[0]
