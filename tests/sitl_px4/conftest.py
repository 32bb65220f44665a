"""Module-scoped fixtures for the PX4 SITL tests: one namespace, one LCM probe, the PX4s booted once.

PX4 needs ~40 s from start to being ready to arm, so a module boots its vehicles once and its tests share
them, each leaving them landed and disarmed in STANDBY. The probe and work-directory fixtures are the
ArduCopter SITL tests'.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.conftest import _netns_reason
from tests.netns import NetNamespace
from tests.sitl_arducopter.conftest import sitl_dir, sitl_probe
from tests.sitl_px4.harness import sitl_missing

__all__ = ["sitl_dir", "sitl_netns", "sitl_probe"]


@pytest.fixture(scope="module")
def sitl_netns() -> Iterator[NetNamespace]:
    reason = sitl_missing() or _netns_reason()
    if reason:
        pytest.skip(reason)
    with NetNamespace() as ns:
        yield ns
