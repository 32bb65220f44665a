"""Module-scoped fixtures for the PX4 SITL tests: one namespace, one LCM probe, the PX4s booted once.

PX4 needs ~40 s from start to being ready to arm, so a module boots its vehicles once and its tests share
them, each leaving them landed and disarmed in STANDBY. The probe and work-directory fixtures are the
ArduCopter SITL tests'.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from typing import Any

import pytest

from tests.harness.netns import NetNamespace, private_netns
from tests.sitl_arducopter.conftest import sitl_dir, sitl_probe
from tests.sitl_px4.harness import sitl_missing

__all__ = ["sitl_dir", "sitl_netns", "sitl_probe"]


@pytest.fixture(scope="module")
def sitl_netns() -> Iterator[NetNamespace]:
    with private_netns(missing=sitl_missing()) as ns:
        yield ns


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, Any, Any]:
    """Each phase's report on its test item (``rep_call``): a flight test lands the vehicle only after
    a failure."""
    report = yield
    setattr(item, f"rep_{report.when}", report)
    return report
