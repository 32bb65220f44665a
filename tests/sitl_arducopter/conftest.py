"""Module-scoped fixtures for the ArduCopter SITL tests: one namespace, one LCM probe, one booted vehicle.

ArduCopter needs ~40 s from start to being ready to arm, so a module boots its vehicle once and its tests
share it, each leaving it landed and disarmed in STANDBY (`landed`), in the order the module lists them.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import Probe
from tests.harness.netns import NetNamespace, private_netns
from tests.sitl_arducopter.harness import sitl_missing


@pytest.fixture(scope="module")
def sitl_netns() -> Iterator[NetNamespace]:
    with private_netns(missing=sitl_missing()) as ns:
        yield ns


@pytest.fixture(scope="module")
def sitl_probe(sitl_netns: NetNamespace) -> Iterator[Probe]:
    yield Probe.start(sitl_netns)


@pytest.fixture(scope="module")
def sitl_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("sitl")
