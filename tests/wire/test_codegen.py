"""The generated message modules and their stubs must match lcmtypes/ exactly: stale or hand-edited
code fails here."""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest

from antalate_lcm.tools import codegen as _codegen
from antalate_lcm.wire.topics import MESSAGE_TYPES
from tests.harness.lcm_tables import dimensions, slots, typenames


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


def test_a_hand_edited_or_missing_stub_is_detected(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    copy = tmp_path / "msgs"
    shutil.copytree(_codegen.MSGS_DIR, copy)
    target = copy / "header_t.pyi"
    target.write_text(target.read_text().replace("mac: bytes", "mac: list[int]"))
    (copy / "payload_t.pyi").unlink()
    monkeypatch.setattr(_codegen, "MSGS_DIR", copy)
    assert _codegen.stale_files() == ["payload_t.pyi", "header_t.pyi"]


def test_every_lcm_file_has_a_module_a_stub_and_a_topic_type() -> None:
    names = {p.stem for p in _codegen.lcm_files()}
    assert names - {"header_t"} == set(MESSAGE_TYPES)
    for name in names:
        assert (_codegen.MSGS_DIR / f"{name}.py").exists()
        assert (_codegen.MSGS_DIR / f"{name}.pyi").exists()


def _stub_fields(name: str) -> dict[str, str]:
    tree = ast.parse((_codegen.MSGS_DIR / f"{name}.pyi").read_text())
    (cls,) = [node for node in tree.body if isinstance(node, ast.ClassDef)]
    return {
        node.target.id: ast.unparse(node.annotation)
        for node in cls.body
        if isinstance(node, ast.AnnAssign)
        and isinstance(node.target, ast.Name)
        and not ast.unparse(node.annotation).startswith(("ClassVar", "Final"))
    }


def set_length(msg: object, dims: list[str | int], n: int) -> None:
    """Set the length field a variable-length array's first dimension names."""
    field = dims[0]
    assert isinstance(field, str), f"a fixed-size array ({field}) has no length field"
    setattr(msg, field, n)


def test_stub_field_types_are_what_decode_produces() -> None:
    """Decode a message with every array filled and compare each field's runtime type with its stub."""
    header_fields = _stub_fields("header_t")
    assert header_fields == {"utime": "int", "agent": "str", "seq": "int", "mac_len": "int", "mac": "bytes"}
    for name, msg_type in MESSAGE_TYPES.items():
        fields = _stub_fields(name)
        assert list(fields) == list(slots(msg_type))
        msg = msg_type()
        msg.header.mac, msg.header.mac_len = b"\x01\x02", 2
        for slot, dims in zip(slots(msg_type), dimensions(msg_type), strict=True):
            if dims and fields[slot] == "list[str]":
                setattr(msg, slot, ["a", "b"])
                set_length(msg, dims, 2)
            elif dims and fields[slot] == "bytes":
                setattr(msg, slot, b"xy")
                set_length(msg, dims, 2)
            elif dims and fields[slot] in ("Sequence[float]", "Sequence[int]", "list[bool]"):
                # several arrays may share one length field (peer_scan_t): fill every one of them
                item = {"Sequence[float]": 1.5, "Sequence[int]": 3, "list[bool]": True}[fields[slot]]
                setattr(msg, slot, [item, item])
                set_length(msg, dims, 2)
        decoded = msg_type.decode(msg.encode())
        for slot, annotation in fields.items():
            value = getattr(decoded, slot)
            if annotation.startswith("Sequence["):  # numbers: a tuple decoded, a list built by hand
                assert isinstance(value, tuple) and value, (name, slot)
                inner = annotation.removeprefix("Sequence[").removesuffix("]")
                assert all(type(item).__name__ == inner for item in value), (name, slot, value)
            elif annotation.startswith("list["):
                assert isinstance(value, list) and value, (name, slot)
                inner = annotation.removeprefix("list[").removesuffix("]")
                assert all(type(item).__name__ == inner for item in value), (name, slot, value)
            else:
                assert type(value).__name__ == annotation, (name, slot, annotation, value)


def test_every_message_starts_with_a_header() -> None:
    for msg_type in MESSAGE_TYPES.values():
        assert slots(msg_type)[0] == "header"
        assert typenames(msg_type)[0] == "antalate_lcm.msgs.header_t"
