"""``antalate types``: the packaged ``.lcm`` copy stays exact, and every language gets bindings (Go's
own checks are in ``tests/tools/test_types_go.py``)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from antalate_lcm.apps import types_cmd
from antalate_lcm.tools import codegen as _codegen
from tests import REPO

TYPE_NAMES = sorted(p.stem for p in _codegen.SOURCE_LCMTYPES_DIR.glob("*.lcm"))


def test_packaged_lcm_files_are_an_exact_copy_of_lcmtypes() -> None:
    assert TYPE_NAMES, "no .lcm files in lcmtypes/"
    assert _codegen.stale_packaged_types() == [], (
        "run `make gen`: antalate_lcm/lcmtypes/ differs from lcmtypes/"
    )


def test_an_edited_or_missing_packaged_file_is_detected(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    copy = tmp_path / "lcmtypes"
    monkeypatch.setattr(_codegen, "PACKAGED_LCMTYPES_DIR", copy)
    _codegen.copy_packaged_types()
    assert _codegen.stale_packaged_types() == []
    (copy / "payload_t.lcm").unlink()
    edited = copy / "mc_state_t.lcm"
    edited.write_text(edited.read_text().replace("MISSION", "MISSIONS"))
    assert _codegen.stale_packaged_types() == ["payload_t.lcm", "mc_state_t.lcm"]


def test_installed_package_reads_its_own_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without a source tree next to the package (a wheel install), the packaged copy is used."""
    monkeypatch.setattr(_codegen, "SOURCE_LCMTYPES_DIR", tmp_path / "no-such-dir")
    assert _codegen._lcmtypes_dir() == _codegen.PACKAGED_LCMTYPES_DIR
    monkeypatch.setattr(_codegen, "SOURCE_LCMTYPES_DIR", REPO / "lcmtypes")
    assert _codegen._lcmtypes_dir() == REPO / "lcmtypes"


@pytest.mark.parametrize(
    ("lang", "expected"),
    [
        ("c", [f"antalate_lcm_msgs_{n}.{ext}" for n in TYPE_NAMES for ext in ("c", "h")]),
        ("cpp", [f"antalate_lcm/msgs/{n}.hpp" for n in TYPE_NAMES]),
        ("java", [f"antalate_lcm/msgs/{n}.java" for n in TYPE_NAMES]),
        ("python", [f"antalate_lcm/msgs/{n}.py" for n in TYPE_NAMES]),
        ("lua", [f"antalate_lcm/msgs/{n}.lua" for n in TYPE_NAMES]),
        ("csharp", [f"antalate_lcm/msgs/{n}.cs" for n in TYPE_NAMES]),
        ("go", [f"antalate_lcm/msgs/{n}.go" for n in TYPE_NAMES]),
        ("lcm", [f"{n}.lcm" for n in TYPE_NAMES]),
    ],
)
def test_each_language_gets_one_binding_per_type(tmp_path: Path, lang: str, expected: list[str]) -> None:
    written = types_cmd.write_types(lang, tmp_path / lang)
    names = {p.relative_to(tmp_path / lang).as_posix() for p in written}
    assert set(expected) <= names, sorted(set(expected) - names)


def test_c_binding_hashes_like_python(tmp_path: Path) -> None:
    """The C binding is the same type as the Python one: the base hash lcm-gen computed from the
    .lcm file is the same literal in both (the fingerprint is built from it and the nested types')."""
    types_cmd.write_types("c", tmp_path)
    for name in TYPE_NAMES:
        py = (_codegen.MSGS_DIR / f"{name}.py").read_text()
        c = (tmp_path / f"antalate_lcm_msgs_{name}.c").read_text()
        py_hash = re.search(r"tmphash = \((0x[0-9a-f]+)", py)
        c_hash = re.search(r"uint64_t hash = \(uint64_t\)(0x[0-9a-f]+)LL", c)
        assert py_hash and c_hash, name
        assert int(py_hash[1], 16) == int(c_hash[1], 16), name


def test_cli_rejects_an_unknown_language_and_an_unwritable_folder(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "types", "--lang", "cobol", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert proc.returncode == 2 and "invalid choice: 'cobol'" in proc.stderr, proc.stderr
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    proc = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "types", "--lang", "c", "--out", str(blocker / "sub")],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    assert (
        proc.stderr.startswith(f"antalate: cannot create {blocker / 'sub'}")
        and "Traceback" not in proc.stderr
    )
