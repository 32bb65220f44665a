"""Fixtures of the LAN tests: skip with the reason where no simulated LAN can be built."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from tests.lan.topology import Lan, lan_unavailable

_REASON: list[str | None] = []


def lan_reason() -> str | None:
    """Checked once per session: building a throw-away one-host LAN is the only honest test."""
    if not _REASON:
        _REASON.append(lan_unavailable())
    return _REASON[0]


@pytest.fixture
def need_lan() -> None:
    reason = lan_reason()
    if reason:
        pytest.skip(f"no simulated LAN: {reason}")


@pytest.fixture
def make_lan(need_lan: None) -> Iterator[Callable[..., Lan]]:
    """``make_lan(k or names)`` -> a built :class:`Lan`, torn down after the test whatever happens."""
    lans: list[Lan] = []

    def make(hosts: int | list[str]) -> Lan:
        lan = Lan(hosts)
        lans.append(lan)
        return lan.__enter__()

    yield make
    for lan in lans:
        lan.close()
