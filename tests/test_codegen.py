"""The generated message modules must match lcmtypes/ exactly: stale or hand-edited code fails here."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from antalate_lcm import _codegen
from antalate_lcm.topics import MESSAGE_TYPES


def test_generated_code_is_fresh() -> None:
    stale = _codegen.stale_files()
    assert stale == [], f"regenerate with `make gen`: stale or hand-edited: {stale}"


def test_a_hand_edit_is_detected(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    copy = tmp_path / "msgs"
    shutil.copytree(_codegen.MSGS_DIR, copy)
    target = copy / "mc_state_t.py"
    target.write_text(target.read_text().replace("MISSION = 3", "MISSION = 4"))
    monkeypatch.setattr(_codegen, "MSGS_DIR", copy)
    assert _codegen.stale_files() == ["mc_state_t.py"]


def test_a_missing_module_is_detected(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    copy = tmp_path / "msgs"
    shutil.copytree(_codegen.MSGS_DIR, copy)
    (copy / "payload_t.py").unlink()
    monkeypatch.setattr(_codegen, "MSGS_DIR", copy)
    assert _codegen.stale_files() == ["payload_t.py"]


def test_every_lcm_file_has_a_module_and_a_topic_type() -> None:
    names = {p.stem for p in _codegen.lcm_files()}
    assert names - {"header_t"} == set(MESSAGE_TYPES)
    for name in names:
        assert (_codegen.MSGS_DIR / f"{name}.py").exists()


def test_every_message_starts_with_a_header() -> None:
    for msg_type in MESSAGE_TYPES.values():
        assert msg_type.__slots__[0] == "header"
        assert msg_type.__typenames__[0] == "antalate_lcm.msgs.header_t"
