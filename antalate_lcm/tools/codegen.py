"""Generate the Python message modules from ``lcmtypes/`` with the ``lcm-gen`` that ships in the lcm wheel.

The generated modules are committed (so a plain ``pip install`` needs no code generator) and
``tests/wire/test_codegen.py`` fails when they are stale against ``lcmtypes/`` or were edited by hand.

lcm-gen's Python has no annotations, so beside every ``<type>.py`` this also writes ``<type>.pyi``:
the same surface (fields, constants, ``encode``/``decode``, fingerprints) with Python types, so a
user's ``msg.header.utime = "now"`` fails in their type checker instead of in ``struct.pack`` on a
vehicle. The stub is read off the generated module itself (``__slots__``, ``__typenames__``,
``__dimensions__``, constants), so it cannot describe anything lcm-gen did not emit.
Run ``python -m antalate_lcm.tools.codegen`` (or ``make gen``) after editing a ``.lcm`` file.

``lcmtypes/`` at the repository root stays the source of truth; ``make gen`` also copies the ``.lcm``
files into ``antalate_lcm/lcmtypes/`` so they travel inside the wheel: an installed antalate has no
source tree, and ``antalate spy`` / ``antalate types`` still need the definitions.
"""

from __future__ import annotations

import ast
import filecmp
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # antalate_lcm/
REPO_ROOT = PACKAGE_DIR.parent
SOURCE_LCMTYPES_DIR = REPO_ROOT / "lcmtypes"
PACKAGED_LCMTYPES_DIR = PACKAGE_DIR / "lcmtypes"


def _lcmtypes_dir() -> Path:
    """The source tree's ``lcmtypes/`` in a checkout (an edit counts before ``make gen``), else the
    copy installed with the package."""
    if SOURCE_LCMTYPES_DIR.is_dir() and (REPO_ROOT / "pyproject.toml").is_file():
        return SOURCE_LCMTYPES_DIR
    return PACKAGED_LCMTYPES_DIR


LCMTYPES_DIR = _lcmtypes_dir()
MSGS_DIR = PACKAGE_DIR / "msgs"
_MSGS_SUBPATH = Path("antalate_lcm") / "msgs"
_MSGS_PACKAGE = "antalate_lcm.msgs"
# The file kinds a generation writes into ``msgs/``: lcm-gen's modules and their stubs.
_GENERATED_GLOBS = ("*.py", "*.pyi")

# LCM primitive → the Python type lcm-gen's encode/decode put in the field.
_PRIMITIVE_TYPES = {
    "int8_t": "int",
    "int16_t": "int",
    "int32_t": "int",
    "int64_t": "int",
    "byte": "int",
    "float": "float",
    "double": "float",
    "string": "str",
    "boolean": "bool",
}


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


def _lcm_gen(*options: str) -> None:
    """Run lcm-gen with ``options`` over every ``.lcm`` file; its output is kept for the
    `subprocess.CalledProcessError` it raises on failure."""
    subprocess.run(
        [lcm_tool("lcm-gen"), *options, *map(str, lcm_files())], check=True, capture_output=True, text=True
    )


def generate_python(out_dir: Path) -> Path:
    """Run lcm-gen for Python into ``out_dir``, add the stubs, return the generated ``msgs`` folder."""
    _lcm_gen("--python", "--ppath", str(out_dir))
    msgs_dir = out_dir / _MSGS_SUBPATH
    write_stubs(msgs_dir)
    return msgs_dir


def _literal_list(node: ast.ClassDef, name: str) -> list[object]:
    for statement in node.body:
        if (
            isinstance(statement, ast.Assign)
            and len(statement.targets) == 1
            and isinstance(statement.targets[0], ast.Name)
            and statement.targets[0].id == name
        ):
            value = ast.literal_eval(statement.value)
            if isinstance(value, list):
                return value
    raise ValueError(f"lcm-gen output changed: class {node.name} has no literal {name} list")


def _field_type(typename: str, dimensions: list[object] | None, own_class: str) -> str:
    """The Python type lcm-gen stores: a byte array decodes to ``bytes`` (one ``read``), the innermost
    array of numbers to a tuple (one ``struct.unpack``; a list when built by hand, hence
    ``Sequence``), every other array to nested lists, a nested struct to its class."""
    if typename.startswith(f"{_MSGS_PACKAGE}."):
        base = typename.rsplit(".", 1)[1]
    elif typename in _PRIMITIVE_TYPES:
        base = _PRIMITIVE_TYPES[typename]
    else:
        raise ValueError(f"{own_class}: unknown LCM type {typename!r}")
    depth = len(dimensions or [])
    if typename == "byte" and depth:
        base, depth = "bytes", depth - 1
    elif base in ("int", "float") and depth:
        base, depth = f"Sequence[{base}]", depth - 1
    for _ in range(depth):
        base = f"list[{base}]"
    return base


def python_stub(source: str) -> str:
    """The ``.pyi`` text for one lcm-gen Python module (its single message class)."""
    tree = ast.parse(source)
    (cls,) = [node for node in tree.body if isinstance(node, ast.ClassDef)]
    name = cls.name
    slots = [str(slot) for slot in _literal_list(cls, "__slots__")]
    typenames = [str(t) for t in _literal_list(cls, "__typenames__")]
    dimensions = _literal_list(cls, "__dimensions__")
    constants = [
        (statement.targets[0].id, statement.value.value)
        for statement in cls.body
        if isinstance(statement, ast.Assign)
        and len(statement.targets) == 1
        and isinstance(statement.targets[0], ast.Name)
        and not statement.targets[0].id.startswith("_")
        and isinstance(statement.value, ast.Constant)
        and isinstance(statement.value.value, (int, float))
    ]
    fields = [
        (slot, _field_type(typename, dims if isinstance(dims, list) else None, name))
        for slot, typename, dims in zip(slots, typenames, dimensions, strict=True)
    ]
    sequence = any("Sequence[" in annotation for _, annotation in fields)
    nested = sorted({t.rsplit(".", 1)[1] for t in typenames if t.startswith(f"{_MSGS_PACKAGE}.")} - {name})
    lines = [
        f'"""Types of the lcm-gen module ``{_MSGS_PACKAGE}.{name}``: generated by antalate_lcm.tools.codegen',
        'from the module itself; regenerate with `make gen`, never edit by hand."""',
        "",
        *(["from collections.abc import Sequence"] if sequence else []),
        f"from typing import BinaryIO, ClassVar{', Final' if constants else ''}",
        "",
        *[f"from {_MSGS_PACKAGE}.{other} import {other}" for other in nested],
        *([""] if nested else []),
        f"class {name}:",
        f"    __slots__ = {slots!r}",
        "    __typenames__: ClassVar[list[str]]",
        "    __dimensions__: ClassVar[list[list[str | int] | None]]",
    ]
    lines += [f"    {constant}: Final = {value!r}" for constant, value in constants]
    lines += [f"    {slot}: {annotation}" for slot, annotation in fields]
    lines += [
        "    _packed_fingerprint: ClassVar[bytes | None]",
        "    def __init__(self) -> None: ...",
        "    def encode(self) -> bytes: ...",
        "    def _encode_one(self, buf: BinaryIO) -> None: ...",
        "    @staticmethod",
        f"    def decode(data: bytes | BinaryIO) -> {name}: ...",
        "    @staticmethod",
        f"    def _decode_one(buf: BinaryIO) -> {name}: ...",
        "    @staticmethod",
        "    def _get_hash_recursive(parents: list[type]) -> int: ...",
        "    @staticmethod",
        "    def _get_packed_fingerprint() -> bytes: ...",
        "    def get_hash(self) -> int: ...",
    ]
    return "\n".join(lines) + "\n"


def write_stubs(msgs_dir: Path) -> None:
    """Write ``<type>.pyi`` beside every generated ``<type>.py`` (not the package ``__init__``)."""
    for module in sorted(msgs_dir.glob("*.py")):
        if module.name != "__init__.py":
            module.with_suffix(".pyi").write_text(python_stub(module.read_text()))


def generate_java(out_dir: Path) -> Path:
    """Run lcm-gen for Java into ``out_dir`` (used by ``antalate spy`` and the cross-language test)."""
    _lcm_gen("--java", "--jpath", str(out_dir))
    return out_dir


def stale_files() -> list[str]:
    """Names of generated files that differ from a fresh generation (empty when up to date)."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = generate_python(Path(tmp))
        fresh_names = {p.name for glob in _GENERATED_GLOBS for p in fresh.glob(glob)}
        committed = {p.name for glob in _GENERATED_GLOBS for p in MSGS_DIR.glob(glob)}
        problems = sorted(fresh_names ^ committed)
        for name in sorted(fresh_names & committed):
            if not filecmp.cmp(fresh / name, MSGS_DIR / name, shallow=False):
                problems.append(name)
        return problems


def regenerate() -> None:
    """Replace the committed modules and stubs in ``msgs/`` with a fresh generation."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = generate_python(Path(tmp))
        MSGS_DIR.mkdir(parents=True, exist_ok=True)
        for glob in _GENERATED_GLOBS:
            for old in MSGS_DIR.glob(glob):
                old.unlink()
            for new in fresh.glob(glob):
                shutil.copy2(new, MSGS_DIR / new.name)


if __name__ == "__main__":
    regenerate()
    copy_packaged_types()
    print(f"generated {len(list(MSGS_DIR.glob('*.py')))} modules in {MSGS_DIR}")
