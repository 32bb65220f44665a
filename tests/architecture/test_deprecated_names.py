"""The old names of the public modules moved into layer folders (issue #26) keep working for one
release, with a DeprecationWarning, and give the same objects as the new names (docs/architecture.md,
"Deprecated names")."""

from __future__ import annotations

import ast
import re
import subprocess
import sys

import pytest

from antalate_lcm.base.deprecation import MOVED_MODULES, RENAMED_NAMES
from tests import REPO
from tests.architecture.doc_tables import section_rows, section_table

#: The moved modules (old, new), from the one table (base.deprecation.MOVED_MODULES).
SHIMS = list(MOVED_MODULES.items())


@pytest.mark.parametrize(("old", "new"), SHIMS)
def test_the_old_name_warns_and_gives_the_same_objects(old: str, new: str) -> None:
    """A fresh interpreter, so the warning is the first import's (a module warns once, when imported)."""
    program = (
        "import importlib, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        f"new = importlib.import_module({new!r})\n"
        "public = [n for n in vars(new) if not n.startswith('_')]\n"
        "assert public and all(getattr(old, n) is getattr(new, n) for n in public), 'not the same objects'\n"
        "assert [w for w in caught if w.category is DeprecationWarning and "
        f"{new!r} in str(w.message)], [str(w.message) for w in caught]\n"
    )
    proc = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_the_warning_points_at_the_users_import() -> None:
    """``base.deprecation.moved_module`` warns from inside the shim: the warning must name the line that
    imported the old name (what a user fixes), not the shim or the helper."""
    program = (
        "import warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    import antalate_lcm.geo\n"
        "print([(w.filename, w.lineno) for w in caught if w.category is DeprecationWarning])\n"
    )
    proc = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[('<string>', 4)]"


#: Imports every module of the three packages but the old names, recording the warnings of each (a
#: library may change the warning filters while it is imported, so none is relied upon).
WALK = """
import importlib, pkgutil, sys, warnings
old = set(sys.argv[1:])
count, used = 0, []
for package in ("antalate_lcm", "operator_tui", "behaviors"):
    for info in pkgutil.walk_packages(importlib.import_module(package).__path__, package + "."):
        if info.name in old or info.name.endswith(".__main__"):
            continue
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                importlib.import_module(info.name)
            except ModuleNotFoundError as exc:  # an extra that is not installed, never one of ours
                if (exc.name or "").split(".")[0] in ("antalate_lcm", "operator_tui", "behaviors"):
                    raise
        used += [f"{info.name}: {w.message}" for w in caught if str(w.message).split(" is deprecated")[0] in old]
        count += 1
print(count)
sys.exit("\\n".join(used) or None)
"""


def test_nothing_in_the_project_imports_an_old_name() -> None:
    """The shims are for users: every module of the packages imports the new names (an old one would warn)."""
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            WALK,
            *(old for old, _ in SHIMS),
            *(f"{m}.{o}" for m, o, _ in RENAMED),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout) > 100  # the walk saw the packages


#: Names renamed to the vocabulary (docs/architecture.md, "Vocabulary"): (module, old, new), from the one
#: table (base.deprecation.RENAMED_NAMES).
RENAMED = [(module, old, new) for module, names in RENAMED_NAMES.items() for old, new in names.items()]

DOC = REPO / "docs" / "architecture.md"


def test_the_docs_table_lists_exactly_the_deprecated_modules_and_names() -> None:
    """docs/architecture.md's "Deprecated names" tells users what to import instead: each of its module and
    name rows is a moved module or a renamed name of base.deprecation, and each of those is a row (the
    attribute rows, which name a class, are `renamed_attribute`'s: the next test)."""
    doc = {
        old: new.strip("`")
        for old, new in section_table(DOC.read_text("utf-8"), "### Deprecated names").items()
    }
    code = dict(MOVED_MODULES) | {f"{m}.{old}": f"{m}.{new}" for m, old, new in RENAMED}
    assert {old: new for old, new in doc.items() if old not in code} == {}, "in the doc, not in the code"
    assert {old: new for old, new in code.items() if old not in doc} == {}, "in the code, not in the doc"
    assert doc == code


def renamed_attributes() -> set[str]:
    """``Class.old`` for every `renamed_attribute` in the packages' class bodies, read from the source."""
    found = set()
    for package in ("antalate_lcm", "operator_tui", "behaviors"):
        for path in sorted((REPO / package).rglob("*.py")):
            for cls in ast.walk(ast.parse(path.read_text("utf-8"), str(path))):
                if not isinstance(cls, ast.ClassDef):
                    continue
                body = [n for top in cls.body for n in (top.body if isinstance(top, ast.If) else [top])]
                found |= {
                    f"{cls.name}.{target.id}"
                    for node in body
                    if isinstance(node, ast.Assign)
                    and isinstance(node.value, ast.Call)
                    and isinstance(node.value.func, ast.Name)
                    and node.value.func.id == "renamed_attribute"
                    for target in node.targets
                    if isinstance(target, ast.Name)
                }
    return found


def test_the_docs_table_lists_exactly_the_renamed_attributes() -> None:
    """The table's attribute rows name ``Class.old`` (and ``.old`` for a second one of the same class):
    they are exactly the `renamed_attribute` class attributes of the source."""
    in_doc = set()
    for first, *_ in section_rows(DOC.read_text("utf-8"), "### Deprecated names"):
        owner = ""
        for span in re.findall(r"`([^`]+)`", first):
            name = span.removesuffix("()")
            if name[:1].isupper() and "." in name:
                owner = name.split(".")[0]
                in_doc.add(name)
            elif name.startswith(".") and owner:
                in_doc.add(owner + name)
    in_code = renamed_attributes()
    assert in_doc - in_code == set(), "in the doc, not in the code"
    assert in_code - in_doc == set(), "in the code, not in the doc"
    assert len(in_code) >= 6  # the reader sees them (HlcNode.autopilot, AgentPlan.autopilot, ...)


@pytest.mark.parametrize(("module", "old", "new"), RENAMED)
def test_an_old_name_warns_and_is_the_new_one(module: str, old: str, new: str) -> None:
    import importlib

    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:  # an optional extra (djitellopy, cflib) that is not installed
        pytest.skip(str(exc))
    with pytest.warns(DeprecationWarning, match=f"{old} is deprecated: use .*{new}"):
        value = getattr(mod, old)
    assert value is getattr(mod, new)


def test_an_old_submodule_is_the_new_module() -> None:
    """A config naming ``antalate_lcm.autopilot.sim:SimAutopilot`` loads the very class it did."""
    program = (
        "import importlib, warnings\n"
        "warnings.simplefilter('ignore')\n"
        "from antalate_lcm.base.plugins import load_plugin\n"
        "from antalate_lcm.vehicles import VehicleAdapter\n"
        "from antalate_lcm.vehicles.sim import SimAdapter\n"
        "old = importlib.import_module('antalate_lcm.autopilot.sim')\n"
        "assert old is importlib.import_module('antalate_lcm.vehicles.sim')\n"
        "assert old.__spec__.name == 'antalate_lcm.vehicles.sim'\n"
        "assert load_plugin('antalate.autopilots', 'antalate_lcm.autopilot.sim:SimAutopilot', VehicleAdapter) is SimAdapter\n"
    )
    proc = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_an_old_attribute_warns_and_is_the_new_one() -> None:
    """``HlcNode.autopilot`` and ``AgentPlan.autopilot`` (issue #26: they hold the vehicle adapter and
    its plan) read ``adapter``, warning each time, and the node's writes it; built by the real agent
    path on the in-memory transport."""
    from antalate_lcm.agent.hlc.node import HlcNode
    from antalate_lcm.core.config import parse_config
    from antalate_lcm.core.node import Context
    from antalate_lcm.runtime.agent import agent_nodes, validate
    from antalate_lcm.vehicles.sim import SimAdapter

    doc = {"agent": {"name": "d1"}, "buses": {"lan": "memq://"}, "hlc": {"autopilot": "sim"}}
    context = Context.in_process({"lan": "memq://"})
    try:
        config = parse_config(doc, "<deprecated>")
        plan = validate(config)
        with pytest.warns(
            DeprecationWarning, match=r"plan\.AgentPlan\.autopilot is deprecated: use .*AgentPlan\.adapter"
        ):
            assert plan.autopilot is plan.adapter  # type: ignore[attr-defined]
        (hlc,) = (n for n in agent_nodes(config, context, plan) if isinstance(n, HlcNode))
        warned = r"antalate_lcm\.agent\.hlc\.node\.HlcNode\.autopilot is deprecated: use .*HlcNode\.adapter"
        with pytest.warns(DeprecationWarning, match=warned):
            assert hlc.autopilot is hlc.adapter  # type: ignore[attr-defined]
        other = SimAdapter({}, clock=context.executor.clock)
        with pytest.warns(DeprecationWarning, match=warned):
            hlc.autopilot = other  # type: ignore[attr-defined]
        assert hlc.adapter is other
        with pytest.warns(
            DeprecationWarning, match=r"core\.context\.Context\.bus is deprecated: use .*Context\.buses"
        ):
            assert context.bus is context.buses  # type: ignore[attr-defined]
    finally:
        context.close()


def test_the_gcs_nodes_old_link_is_its_ground_station_connection() -> None:
    """``GcsNode.link`` held the pymavlink connection to the ground station, which is not a link in the
    vocabulary (an adapter's I/O with its vehicle): it is ``ground`` now, and the old name reads it."""
    from pymavlink import mavutil

    from antalate_lcm.apps.gcs.server import GcsNode
    from antalate_lcm.apps.gcs.view import GcsView
    from antalate_lcm.core.config import parse_config
    from antalate_lcm.core.node import Context, NodeSettings

    config = parse_config({"agent": {"name": "gcs"}, "buses": {"lan": "memq://"}}, "<deprecated>")
    context = Context.in_process({"lan": "memq://"})
    ground = mavutil.mavlink_connection("udpout:127.0.0.1:14550", source_system=255)
    try:
        node = GcsNode(NodeSettings.from_config(config), context, GcsView(), ground, commands=False)
        with pytest.warns(
            DeprecationWarning, match=r"server\.GcsNode\.link is deprecated: use .*GcsNode\.ground"
        ):
            assert node.link is ground is node.ground  # type: ignore[attr-defined]
    finally:
        ground.close()
        context.close()


def test_the_hlc_machines_old_names_are_its_vehicle_snapshot_and_input() -> None:
    """``HighLevelControl.autopilot`` held the last `VehicleState` and ``on_autopilot`` took it: both are
    the vehicle's (the vocabulary's "vehicle"), so they are ``vehicle`` and ``on_vehicle``; the old names
    warn and reach the new ones."""
    from antalate_lcm.agent.hlc.machine import HighLevelControl
    from antalate_lcm.vehicles import VehicleState

    hlc = HighLevelControl()
    snapshot = VehicleState(link_age=0.1)
    with pytest.warns(
        DeprecationWarning, match=r"HighLevelControl\.on_autopilot is deprecated: use .*\.on_vehicle"
    ):
        hlc.on_autopilot(snapshot, 1.0)  # type: ignore[attr-defined]
    assert hlc.vehicle is snapshot
    with pytest.warns(
        DeprecationWarning, match=r"HighLevelControl\.autopilot is deprecated: use .*\.vehicle"
    ):
        assert hlc.autopilot is snapshot  # type: ignore[attr-defined]


def test_the_mavlink_vehicles_old_autopilot_state_is_its_vehicle_state() -> None:
    """``Vehicle.autopilot_state()`` (what a MAVLink autopilot last said, as a `VehicleState`, the
    vocabulary's "vehicle") is ``vehicle_state()``; the old name warns and is the very method."""
    from antalate_lcm.vehicles.mavlink.vehicle import Vehicle
    from antalate_lcm.vehicles.px4.vehicle import Px4Vehicle

    for vehicle in (Vehicle(), Px4Vehicle()):
        with pytest.warns(
            DeprecationWarning, match=r"Vehicle\.autopilot_state is deprecated: use .*\.vehicle_state"
        ):
            old = vehicle.autopilot_state  # type: ignore[attr-defined]
        assert old == vehicle.vehicle_state and old(1.0) == vehicle.vehicle_state(1.0)


#: The test helpers docs/behaviors.md once showed by their old paths (a behavior package's tests may
#: import them): (old module, new module, the names the old one keeps).
TEST_HELPERS = [
    ("tests.polling", "tests.harness.polling", ["wait_for"]),
    (
        "tests.bma_support",
        "tests.harness.bma",
        ["AGENT", "Delayed", "Harness", "ModeSwitcher", "Raiser", "Recorder", "harness", "make_config"],
    ),
]


@pytest.mark.parametrize(("old", "new", "names"), TEST_HELPERS)
def test_an_old_test_helper_warns_and_gives_the_same_objects(old: str, new: str, names: list[str]) -> None:
    """A fresh interpreter in the checkout, as a behavior package's tests would import it."""
    program = (
        "import importlib, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        f"new = importlib.import_module({new!r})\n"
        f"assert all(getattr(old, n) is getattr(new, n) for n in {names!r}), 'not the same objects'\n"
        "assert [w for w in caught if w.category is DeprecationWarning and "
        f"{new!r} in str(w.message)], [str(w.message) for w in caught]\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", program], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert proc.returncode == 0, proc.stderr


def test_a_behavior_named_by_its_old_test_path_loads() -> None:
    """docs/behaviors.md's cascaded arbiter named ``tests.bma_support:ModeSwitcher``: a config that copied
    it loads the very class."""
    program = (
        "import warnings\n"
        "warnings.simplefilter('ignore')\n"
        "from antalate_lcm.base.plugins import load_plugin\n"
        "from antalate_lcm.core.behavior import Behavior\n"
        "from tests.harness.bma import ModeSwitcher\n"
        "assert load_plugin('antalate.behaviors', 'tests.bma_support:ModeSwitcher', Behavior) is ModeSwitcher\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", program], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert proc.returncode == 0, proc.stderr
