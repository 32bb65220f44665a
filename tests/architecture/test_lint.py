"""The tree stays `ruff` clean and formatted, and `mypy --strict` passes on the packages and on tests/
(pyproject.toml holds the rules of both)."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from tests import REPO


def _ruff() -> str:
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (pip install -e '.[dev]')")
    return ruff


def _mypy_cache_dir() -> Path:
    """Beside the interpreter in a venv (kept between runs, and thrown away with the venv of a fresh
    CI clone), else in the temp dir: an incremental run takes a few seconds, a cold one several times that."""
    if sys.prefix != sys.base_prefix:
        return Path(sys.prefix) / ".mypy_cache"
    return Path(tempfile.gettempdir()) / "antalate-mypy-cache"


def test_ruff_clean() -> None:
    proc = subprocess.run(
        [_ruff(), "check", "--output-format", "concise", "."], cwd=REPO, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_ruff_format() -> None:
    proc = subprocess.run([_ruff(), "format", "--check", "."], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, "run `ruff format .`:\n" + proc.stdout + proc.stderr


def test_mypy_gate_covers_the_tests() -> None:
    """The helpers and emulators the tests lean on are checked like the product (only the SITL suites,
    reworked on their own, may stay out for now)."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - exercised only on 3.10
        import tomli as tomllib

    mypy = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["mypy"]
    assert "tests" in mypy["packages"]
    assert not mypy.get("exclude"), mypy["exclude"]  # every test module, the SITL ones too


def test_mypy_strict() -> None:
    """pyproject's [tool.mypy]: strict over antalate_lcm, operator_tui, behaviors and tests, as Python 3.10."""
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (pip install -e '.[dev]')")
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(_mypy_cache_dir())],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
