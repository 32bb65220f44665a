"""The package's structure: layers that only import downwards, no private names across packages, one
exception root.

The layer picture is drawn in docs/architecture.md ("Layers"); `LAYERS` below is the same picture, and
these tests are what keeps it true. They read the source (ast), so a function-level import or one under
``if TYPE_CHECKING:`` counts as much as one at the top of a module.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from antalate_lcm.base.errors import AntalateError
from tests import REPO

PACKAGES = ("antalate_lcm", "operator_tui", "behaviors")

#: Lowest first: (layer, its folder). One folder is one layer: every module of antalate_lcm lives in the
#: folder of its layer; operator_tui and behaviors are whole packages, each a layer. A layer may import
#: its own folder and those below, never one above (docs/architecture.md, "Layers").
LAYERS: list[tuple[str, str]] = [
    ("contract", "msgs"),
    ("base", "base"),
    ("contract tooling", "tools"),
    ("transports", "transports"),
    ("wire", "wire"),
    ("core", "core"),
    ("vehicles", "vehicles"),
    ("station", "station"),
    ("agent", "agent"),
    ("behaviors", "behaviors"),
    ("console", "operator_tui"),
    ("applications", "apps"),
    ("composition root", "runtime"),
]

#: The top level of antalate_lcm is its public surface, not a layer: the package's names (its
#: ``__init__``, which re-exports core and vehicle names; the runtime reads its ``__version__``), the CLI
#: entry, and the old names of moved public modules, kept one release with a DeprecationWarning
#: (DEPRECATED). Each sits with the layer it may import.
DEPRECATED = frozenset(
    {
        "autopilot",
        "lcm_datagram",
        "behavior",
        "geo",
        "peers",
        "ratelimit",
        "security",
        "validation",
        "analysis",
    }
)
SURFACE: dict[str, str] = {"antalate_lcm": "vehicles", "cli": "composition root"} | {
    name: "composition root" for name in DEPRECATED
}

#: Folders that group units of their own (a module or a subpackage each, as they were at the top level
#: before): the cycle rule is about those units (mc <-> hlc was one). Other folders are one unit.
GROUPS = frozenset({"base", "wire", "core", "agent", "apps"})

LAYER_OF: dict[str, int] = {folder: i for i, (_, folder) in enumerate(LAYERS)} | {
    module: [name for name, _ in LAYERS].index(layer) for module, layer in SURFACE.items()
}


@dataclass(frozen=True)
class Import:
    module: str  # the importing module
    line: int
    target: str  # the imported module
    name: str | None  # for ``from target import name``: the name


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_package(module: str) -> bool:
    return (REPO / module.replace(".", "/") / "__init__.py").exists()


def _sources() -> Iterator[Path]:
    for package in PACKAGES:
        yield from sorted((REPO / package).rglob("*.py"))


def _imports(path: Path) -> Iterator[Import]:
    """Every import of one of our packages in ``path``, at any depth (functions, TYPE_CHECKING)."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(module, node.lineno, alias.name, None)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            for alias in node.names:
                submodule = f"{target}.{alias.name}"
                if _is_package(target) and (
                    _is_package(submodule) or (REPO / f"{submodule.replace('.', '/')}.py").exists()
                ):
                    yield Import(module, node.lineno, submodule, None)  # ``from pkg import module``
                else:
                    yield Import(module, node.lineno, target, alias.name)


def _unit(module: str) -> str:
    """The layer folder (or top-level module) a module belongs to."""
    parts = module.split(".")
    if parts[0] != "antalate_lcm":
        return parts[0]
    return parts[1] if len(parts) > 1 else "antalate_lcm"


def _part(module: str) -> str:
    """A unit inside a layer folder (``agent.mc``): what the cycle rule is about (mc <-> hlc was one)."""
    parts = module.split(".")
    if parts[0] != "antalate_lcm" or len(parts) < 3 or parts[1] not in GROUPS:
        return _unit(module)
    return ".".join(parts[1:3])


def _ours(module: str) -> bool:
    return module.split(".")[0] in PACKAGES


ALL_IMPORTS: list[Import] = [imp for path in _sources() for imp in _imports(path) if _ours(imp.target)]


def _where(imp: Import) -> str:
    what = f"from {imp.target} import {imp.name}" if imp.name else f"import {imp.target}"
    return f"{imp.module}:{imp.line}: {what}"


def test_every_unit_has_a_layer() -> None:
    """A new module or subpackage must be placed in the picture (and in docs/architecture.md)."""
    units = {_unit(_module_name(path)) for path in _sources()}
    assert units - set(LAYER_OF) == set()


def test_the_top_level_is_the_public_surface() -> None:
    """Every module lives in its layer's folder; the top level of antalate_lcm holds only the surface."""
    top = REPO / "antalate_lcm"
    modules = {path.stem for path in top.glob("*.py")}
    folders = {path.name for path in top.iterdir() if (path / "__init__.py").exists()}
    assert modules - {"__init__"} - set(SURFACE) == set()
    assert folders - {folder for _, folder in LAYERS} - DEPRECATED == set()  # autopilot/: a package shim


def test_one_folder_is_one_layer() -> None:
    """Each layer is one folder, each folder one layer; a top-level module is never a layer."""
    folders = [folder for _, folder in LAYERS]
    assert len(folders) == len(set(folders)) == len({name for name, _ in LAYERS})
    for folder in folders:
        assert (REPO / "antalate_lcm" / folder / "__init__.py").exists() or (
            REPO / folder / "__init__.py"
        ).exists()
    assert set(SURFACE.values()) <= {name for name, _ in LAYERS}


def test_no_lower_layer_imports_a_higher_one() -> None:
    upward = [
        f"{_where(imp)} ({LAYERS[LAYER_OF[_unit(imp.module)]][0]} imports {LAYERS[LAYER_OF[_unit(imp.target)]][0]})"
        for imp in ALL_IMPORTS
        if LAYER_OF.get(_unit(imp.target), -1) > LAYER_OF.get(_unit(imp.module), len(LAYERS))
    ]
    assert upward == []


def test_no_import_cycle_between_units() -> None:
    """Within a layer units may import each other, but not both ways round (mc ↔ hlc was one)."""
    edges: dict[str, set[str]] = {}
    for imp in ALL_IMPORTS:
        a, b = _part(imp.module), _part(imp.target)
        if a != b:
            edges.setdefault(a, set()).add(b)

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            unit = todo.pop()
            if unit == goal:
                return True
            if unit not in seen:
                seen.add(unit)
                todo.extend(edges.get(unit, ()))
        return False

    cycles = sorted(
        f"{a} -> {b} -> … -> {a}" for a, targets in edges.items() for b in targets if reaches(b, a)
    )
    assert cycles == []


def test_no_private_name_is_imported_from_another_package() -> None:
    """``from x import _name`` is for x's own package; another package gets a public name."""

    def package(module: str) -> str:
        return module if _is_package(module) else module.rpartition(".")[0]

    leaks = [
        _where(imp)
        for imp in ALL_IMPORTS
        if imp.name is not None
        and imp.name.startswith("_")
        and not imp.name.startswith("__")
        and package(imp.target) != package(imp.module)
    ]
    assert leaks == []


def _package_of(module: str) -> str:
    return module if _is_package(module) else module.rpartition(".")[0]


def _private_module_leaks(imports: list[Import]) -> list[str]:
    """Imports of a private module (``pkg._mod``, or anything below it) from outside ``pkg``."""
    leaks = []
    for imp in imports:
        parts = imp.target.split(".")
        private = [i for i, part in enumerate(parts) if part.startswith("_") and not part.startswith("__")]
        if private and _package_of(imp.module) != ".".join(parts[: private[0]]):
            leaks.append(_where(imp))
    return leaks


def test_no_private_module_is_imported_from_another_package() -> None:
    """``pkg._mod`` is ``pkg``'s own (Textual's rule): another package, a subpackage included, imports
    what ``pkg`` makes public -- a name its ``__init__`` re-exports, or a public module."""
    assert _private_module_leaks(ALL_IMPORTS) == []


def test_the_private_module_rule_rejects_what_it_is_about() -> None:
    """The rule sees ``import``, ``from pkg import _mod`` and ``from pkg._mod import name`` from outside,
    and lets the owning package (its ``__init__`` and its modules) use its own private modules."""
    outside = [
        Import("operator_tui.web", 1, "antalate_lcm.station._auth", "sha256_hex"),
        Import("antalate_lcm.runtime.cli", 2, "antalate_lcm.station._db", None),
        Import("behaviors.x", 3, "antalate_lcm.station._file", None),
    ]
    inside = [
        Import("antalate_lcm.station", 4, "antalate_lcm.station._models", None),
        Import("antalate_lcm.station.cli", 5, "antalate_lcm.station._auth", "new_api_key"),
        Import("antalate_lcm.station._app", 6, "antalate_lcm.station._db", "Database"),
    ]
    assert len(_private_module_leaks(outside)) == 3
    assert _private_module_leaks(inside) == []


def test_the_checks_see_function_level_and_relative_imports() -> None:
    """The parser finds what the rules are about: an import inside a function, a relative import."""
    found = {(imp.module, imp.target) for imp in ALL_IMPORTS}
    assert ("antalate_lcm.runtime.interactive", "operator_tui.app") in found  # inside a function
    assert ("antalate_lcm.station", "antalate_lcm.station._models") in found  # ``from . import _models``


# ------------------------------------------------------------------------------ exceptions

#: Private control flow that never leaves its module, so it keeps the base its caller needs.
PRIVATE_EXCEPTIONS = {
    # pydantic turns a ValueError raised in a validator into its ValidationError, which load_config
    # reports as a ConfigError; it must stay a ValueError for pydantic to do that.
    "antalate_lcm.core.config._KeyedError",
    # raised and caught inside the station's body-size middleware.
    "antalate_lcm.station._app._TooLarge",
}


def _exception_classes() -> Iterator[type[BaseException]]:
    for package in PACKAGES:
        root = importlib.import_module(package)
        names = [package] + [m.name for m in pkgutil.walk_packages(root.__path__, f"{package}.")]
        for name in names:
            if name.rpartition(".")[2] == "__main__":
                continue  # running it is what importing it does
            if name.count(".") == 1 and name.rpartition(".")[2] in DEPRECATED:
                continue  # a deprecated name: the same classes as its new module, and a warning
            module = importlib.import_module(name)
            for value in vars(module).values():
                if inspect.isclass(value) and issubclass(value, BaseException) and value.__module__ == name:
                    yield value


def test_every_exception_derives_from_antalate_error() -> None:
    """One root, so ``except AntalateError`` (the CLI, the console) catches whatever antalate raises."""
    classes = list(_exception_classes())
    assert len(classes) > 10  # the walk found the package's exceptions
    strays = [
        f"{cls.__module__}.{cls.__qualname__}"
        for cls in classes
        if not issubclass(cls, AntalateError)
        and f"{cls.__module__}.{cls.__qualname__}" not in PRIVATE_EXCEPTIONS
    ]
    assert strays == []


@pytest.mark.parametrize(
    ("qualified", "stdlib"),
    [
        ("antalate_lcm.vehicles.AutopilotError", RuntimeError),
        ("antalate_lcm.vehicles.UnknownAdapterError", LookupError),
        ("antalate_lcm.vehicles.mavlink.link.LinkClosed", ConnectionError),
        ("antalate_lcm.agent.osc.wire.ReplyError", ValueError),
        ("antalate_lcm.base.strict.StrictError", ValueError),
        ("antalate_lcm.station._station.UnknownTarget", LookupError),
    ],
)
def test_exceptions_keep_the_stdlib_base_callers_catch(qualified: str, stdlib: type[Exception]) -> None:
    """Adding the root must not stop an ``except RuntimeError`` (…) that caught them before."""
    module, _, name = qualified.rpartition(".")
    assert issubclass(getattr(importlib.import_module(module), name), stdlib)


# ------------------------------------------------------------------------------ one name, one class

#: Class names defined in more than one module on purpose or not yet resolved. ``Params`` is the
#: adapters' convention (each adapter's ``[hlc.autopilot_params]`` model, reached as ``<adapter>.Params``).
#: The others are known doubles left to their owners (issue #14); remove a line when it is resolved,
#: never add one for a new class: give it a name of its own.
KNOWN_DOUBLES = {
    "Params",
    "Detection",  # station/sector.py, behaviors/dovrat_swarm/logic.py
    "Direction",  # bridge.py, station/_models.py, behaviors/direction_follow.py
    "DirectionCommand",  # station/_models.py (JSON), analysis/records.py (a log record)
    "MemoryLink",  # vehicles/mavlink/link.py, vehicles/crazyflie/memory.py
    "Telemetry",  # station/_models.py (JSON), operator_tui/board.py
    "Verdict",  # hlc/velocity_guard.py, vehicles/mavlink/setpoints.py
    "_Writer",  # tools/golang_layout.py, vehicles/mavlink/link.py
}


def test_no_new_class_name_is_defined_twice() -> None:
    """``McState`` in two machines, ``OperatorCommand`` meaning two things: one name, one class."""
    where: dict[str, list[str]] = {}
    for path in _sources():
        if "msgs" in path.relative_to(REPO).parts:
            continue  # generated
        for node in ast.parse(path.read_text(), str(path)).body:
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(_module_name(path))
    doubles = {
        name: modules for name, modules in where.items() if len(modules) > 1 and name not in KNOWN_DOUBLES
    }
    assert doubles == {}
