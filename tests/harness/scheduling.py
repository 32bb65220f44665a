"""The order in which the suite's modules reach xdist's workers: longest first, the SITL swarms together.

The suite mostly waits (vehicles climbing, firmware booting, links timing out), so `make test` runs more
workers than cores. What then bounds it is the tail: with xdist's default order (the modules with the
most tests first) the real-firmware modules, each a few long tests, came last and ran on after the rest
had finished. Here the modules go out longest first (a greedy longest-processing-time schedule) from
the times measured in ``tests/harness/module_times.json``; a module not in it counts as `DEFAULT_S`.

The real-firmware modules form two units (`SITL_UNITS`), each run module after module on one worker,
so that at most two of them fly at once: the modules that fly three vehicles at once with PX4's own
flight in one, ArduCopter's flight and failsafes in the other. Six SITL vehicles booting at once on two
cores (four workers each in a SITL module) made PX4's simulated baro and compass time out after
take-off ("Failsafe: blind land") in two full runs of four; three ArduCopters and three PX4s flown
together had starved each other's simulators before. The swarm modules' file lock
(`one_sitl_swarm_at_a_time`) still keeps them apart when the suite is run some other way.

``ANTALATE_MODULE_TIMES=FILE pytest ...`` writes the run's own times per module to FILE, in the format
of ``tests/harness/module_times.json``, to refresh it.
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
#: module -> its unit (the modules not named are each a unit of their own)
SITL_UNITS = {
    "tests/sitl_arducopter/test_safety.py": "sitl-swarms-and-px4",
    "tests/sitl_arducopter/test_swarm.py": "sitl-swarms-and-px4",
    "tests/sitl_px4/test_flight.py": "sitl-swarms-and-px4",
    "tests/sitl_px4/test_swarm.py": "sitl-swarms-and-px4",
    "tests/sitl_arducopter/test_flight.py": "sitl-arducopter",
    "tests/sitl_arducopter/test_failsafes.py": "sitl-arducopter",
}
_RECORDED: defaultdict[str, float] = defaultdict(float)


def module_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def unit_of(nodeid: str) -> str:
    """The work unit a test belongs to: its module, or its module's `SITL_UNITS` entry."""
    module = module_of(nodeid)
    return SITL_UNITS.get(module, module)


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

    def key(item: pytest.Item) -> tuple[float, int]:
        unit = unit_of(item.nodeid)
        return (-unit_s[unit], first[unit])

    items.sort(key=key)  # stable: a unit's tests keep their order


def make_scheduler(config: pytest.Config, log: Any) -> Any:
    """xdist's per-file scheduler, with the SITL units and the collection's order kept."""
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
