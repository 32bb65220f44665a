"""Shared fixtures: private network namespaces and a scriptable LCM probe inside them."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import pytest

from tests.jsonl import JsonLinesProcess
from tests.netns import NetNamespace, netns_unavailable

MCAST_URL = "udpm://239.255.76.67:7667?ttl=0"
_NETNS_REASON: list[str | None] = []


def _netns_reason() -> str | None:
    if not _NETNS_REASON:
        _NETNS_REASON.append(netns_unavailable())
    return _NETNS_REASON[0]


@pytest.fixture
def netns() -> Iterator[NetNamespace]:
    """A private network namespace with multicast on lo; skips with the reason where none can be made."""
    reason = _netns_reason()
    if reason:
        pytest.skip(f"no private network namespace: {reason}")
    with NetNamespace() as ns:
        yield ns


class Probe(JsonLinesProcess):
    """Client side of tests/probe.py: publish, wait for and list messages inside a namespace."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        super().__init__(proc, "the LCM probe")

    def publish(self, channel: str, type_name: str, **fields: Any) -> None:
        assert self.call(op="publish", channel=channel, type=type_name, fields=fields)["ok"]

    def raw(self, channel: str, data: bytes) -> None:
        assert self.call(op="raw", channel=channel, hex=data.hex())["ok"]

    def wait(
        self, channel: str, type_name: str, timeout: float = 10, since: int = 0, **where: Any
    ) -> dict[str, Any] | None:
        reply = self.call(
            op="wait", channel=channel, type=type_name, where=where, timeout=timeout, since=since
        )
        return reply.get("msg") if reply["ok"] else None

    def history(self, channel: str, type_name: str, since: int = 0) -> list[dict[str, Any]]:
        return self.call(op="history", channel=channel, type=type_name, since=since)["msgs"]

    def mark(self) -> int:
        return self.call(op="mark")["index"]


@pytest.fixture
def probe(netns: NetNamespace) -> Iterator[Probe]:
    proc = netns.popen(
        [sys.executable, "-m", "tests.probe", MCAST_URL],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    yield Probe(proc)
