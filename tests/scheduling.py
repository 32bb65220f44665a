"""The order in which the suite's modules reach xdist's workers: longest first, the SITL swarms together.

The suite mostly waits (vehicles climbing, firmware booting, links timing out), so `make test` runs more
workers than cores. What then bounds it is the tail: with xdist's default order (the modules with the
most tests first) the real-firmware modules, each a few long tests, came last and ran on after the rest
had finished. Here the modules go out longest first (a greedy longest-processing-time schedule) from
the times measured in ``tests/module_times.json``; a module not in it counts as `DEFAULT_S`.

The modules that fly three SITL vehicles at once form one unit (`SWARM_UNIT`), run one after another
on one worker: flown together on two cores they starved each other's simulators (a PX4 lost its
simulated sensors, an ArduCopter swarm came 1 cm inside its margin). Their file lock
(`one_sitl_swarm_at_a_time`) still keeps them apart when the suite is run some other way; the unit
keeps the lock from idling a worker.

``ANTALATE_MODULE_TIMES=FILE pytest ...`` writes the run's own times per module to FILE, in the format
of ``tests/module_times.json``, to refresh it.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest

TIMES_FILE = Path(__file__).with_name("module_times.json")
#: s: a module that was not measured (new since the file was written)
DEFAULT_S = 5.0
SWARM_UNIT = "sitl-swarms"
SWARM_MODULES = frozenset(
    {
        "tests/sitl_arducopter/test_safety.py",
        "tests/sitl_arducopter/test_swarm.py",
        "tests/sitl_px4/test_swarm.py",
    }
)
_RECORDED: defaultdict[str, float] = defaultdict(float)


def module_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def unit_of(nodeid: str) -> str:
    """The work unit a test belongs to: its module, or `SWARM_UNIT`."""
    module = module_of(nodeid)
    return SWARM_UNIT if module in SWARM_MODULES else module


def measured_times() -> dict[str, float]:
    try:
        data = json.loads(TIMES_FILE.read_text())
    except (OSError, ValueError):
        return {}
    return {k: float(v) for k, v in data.items() if isinstance(v, (int, float))}


def longest_first(items: list[pytest.Item]) -> None:
    """Reorder `items` in place: units longest first, each unit's tests together and in their order."""
    times = measured_times()
    unit_s: defaultdict[str, float] = defaultdict(float)
    first: dict[str, int] = {}
    for module in {module_of(item.nodeid) for item in items}:
        unit_s[unit_of(module)] += times.get(module, DEFAULT_S)
    for index, item in enumerate(items):
        first.setdefault(unit_of(item.nodeid), index)
    position = {id(item): i for i, item in enumerate(items)}

    def key(item: pytest.Item) -> tuple[float, int, int]:
        unit = unit_of(item.nodeid)
        return (-unit_s[unit], first[unit], position[id(item)])

    items.sort(key=key)


def make_scheduler(config: pytest.Config, log: Any) -> Any:
    """xdist's per-file scheduler, with the swarm modules as one unit and the collection's order kept."""
    from xdist.scheduler import LoadFileScheduling

    class LongestFirst(LoadFileScheduling):  # type: ignore[misc]  # xdist has no type hints
        def _split_scope(self, nodeid: str) -> str:
            return unit_of(nodeid)

    config.option.loadscopereorder = False  # xdist's default puts the units with most tests first
    return LongestFirst(config, log)


def record(report: pytest.TestReport) -> None:
    if os.environ.get("ANTALATE_MODULE_TIMES"):
        _RECORDED[module_of(report.nodeid)] += report.duration


def write_recorded() -> None:
    path = os.environ.get("ANTALATE_MODULE_TIMES")
    if path and _RECORDED:
        ordered = dict(sorted(((k, round(v, 1)) for k, v in _RECORDED.items()), key=lambda kv: -kv[1]))
        Path(path).write_text(json.dumps(ordered, indent=1) + "\n")
