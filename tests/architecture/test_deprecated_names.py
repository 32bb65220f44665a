"""The old names of the public modules moved into layer folders (issue #26) keep working for one
release, with a DeprecationWarning, and give the same objects as the new names (docs/architecture.md,
"Deprecated names")."""

from __future__ import annotations

import subprocess
import sys

import pytest

SHIMS = [
    ("antalate_lcm.behavior", "antalate_lcm.core.behavior"),
    ("antalate_lcm.geo", "antalate_lcm.base.geo"),
    ("antalate_lcm.peers", "antalate_lcm.wire.peers"),
    ("antalate_lcm.ratelimit", "antalate_lcm.base.ratelimit"),
    ("antalate_lcm.security", "antalate_lcm.wire.security"),
    ("antalate_lcm.validation", "antalate_lcm.wire.validation"),
    ("antalate_lcm.analysis", "antalate_lcm.apps.analysis"),
    ("antalate_lcm.autopilot", "antalate_lcm.vehicles"),
    ("operator_tui.link", "operator_tui.node"),
    ("operator_tui.model", "operator_tui.board"),
    ("antalate_lcm.apps.analysis.model", "antalate_lcm.apps.analysis.records"),
    ("antalate_lcm.runtime.commands", "antalate_lcm.runtime.cli"),
    ("antalate_lcm.runtime.clock_link", "antalate_lcm.runtime.clock_client"),
]
#: Deprecated names with a test of their own (they re-export only what users imported).
OTHERS = [
    "antalate_lcm.lcm_datagram",
]


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
            *OTHERS,
            *(f"{m}.{o}" for m, o, _ in RENAMED),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout) > 100  # the walk saw the packages


#: Names renamed to the vocabulary (docs/architecture.md, "Vocabulary"): (module, old, new).
RENAMED = [
    ("antalate_lcm", "Autopilot", "VehicleAdapter"),
    ("antalate_lcm", "AutopilotState", "VehicleState"),
    ("antalate_lcm", "Bus", "Buses"),
    ("antalate_lcm.vehicles", "Autopilot", "VehicleAdapter"),
    ("antalate_lcm.vehicles", "AutopilotState", "VehicleState"),
    ("antalate_lcm.vehicles", "UnknownAutopilotError", "UnknownAdapterError"),
    ("antalate_lcm.vehicles", "available_autopilots", "available_adapters"),
    ("antalate_lcm.vehicles", "load_autopilot", "load_adapter"),
    ("antalate_lcm.base.errors", "UnknownAutopilotError", "UnknownAdapterError"),
    ("antalate_lcm.agent.plan", "AutopilotPlan", "AdapterPlan"),
    ("antalate_lcm.agent.plan", "plan_autopilot", "plan_adapter"),
    ("antalate_lcm.agent.hlc.node", "make_autopilot", "make_adapter"),
    ("antalate_lcm.vehicles.base", "Autopilot", "VehicleAdapter"),
    ("antalate_lcm.vehicles.base", "AutopilotState", "VehicleState"),
    ("antalate_lcm.vehicles.crazyflie", "CrazyflieAutopilot", "CrazyflieAdapter"),
    ("antalate_lcm.vehicles.crazyflie.adapter", "CrazyflieAutopilot", "CrazyflieAdapter"),
    ("antalate_lcm.vehicles.mavlink", "MavlinkAutopilot", "MavlinkAdapter"),
    ("antalate_lcm.vehicles.mavlink.adapter", "MavlinkAutopilot", "MavlinkAdapter"),
    ("antalate_lcm.vehicles.px4", "Px4Autopilot", "Px4Adapter"),
    ("antalate_lcm.vehicles.px4.adapter", "Px4Autopilot", "Px4Adapter"),
    ("antalate_lcm.vehicles.sim", "SimAutopilot", "SimAdapter"),
    ("antalate_lcm.vehicles.sim.adapter", "SimAutopilot", "SimAdapter"),
    ("antalate_lcm.vehicles.tello", "TelloAutopilot", "TelloAdapter"),
    ("antalate_lcm.vehicles.tello.adapter", "TelloAutopilot", "TelloAdapter"),
    ("antalate_lcm.cli", "commands", "subcommands"),
    ("antalate_lcm.core.bus", "Bus", "Buses"),
    ("antalate_lcm.runtime.clock_client", "ClockLink", "ClockClient"),
    ("antalate_lcm.runtime.clock_client", "SimulatedBus", "SimulatedBuses"),
    ("antalate_lcm.runtime.clock_client", "SocketLink", "SocketClockClient"),
    ("antalate_lcm.runtime.time_coordinator", "ClockLink", "ClockClient"),
    ("antalate_lcm.runtime.time_coordinator", "LocalLink", "LocalClockClient"),
    ("antalate_lcm.runtime.time_coordinator", "SimulatedBus", "SimulatedBuses"),
    ("antalate_lcm.runtime.time_coordinator", "SocketLink", "SocketClockClient"),
    ("operator_tui.board", "SwarmModel", "SwarmBoard"),
    ("operator_tui.web", "ConsoleLink", "BrowserTab"),
]


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
    finally:
        context.close()
