"""Fixtures of the WAN tests: skip with the reason where three sites cannot be built."""

from __future__ import annotations

import importlib.util

import pytest

from tests.lan.topology import lan_unavailable

_REASON: list[str | None] = []


@pytest.fixture
def need_wan() -> None:
    if not _REASON:
        _REASON.append(
            "eclipse-zenoh is not installed (pip install -e '.[dev]')"
            if importlib.util.find_spec("zenoh") is None
            else lan_unavailable()
        )
    if _REASON[0]:
        pytest.skip(f"no simulated WAN: {_REASON[0]}")
