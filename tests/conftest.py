"""Shared fixtures: private network namespaces and a scriptable LCM probe inside them."""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import pytest

from antalate_lcm.vehicles import VehicleAdapter
from tests.harness import scheduling
from tests.harness.jsonl import JsonLinesProcess
from tests.harness.netns import MCAST_URL as MCAST_URL
from tests.harness.netns import NetNamespace, netns_reason, private_netns

if TYPE_CHECKING:
    from tests.harness.agents import AgentProcesses

#: The ``user_properties`` key of an attack's verdict (tests/security/conftest.py judges each attack).
ATTACK_PROPERTY = "antalate-attack"
_ATTACKS: dict[str, str] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Tally the attacks (here, in the process that prints the summary: the xdist controller too)."""
    scheduling.record(report)
    for key, value in report.user_properties:
        if key == ATTACK_PROPERTY:
            name, verdict = cast("tuple[str, str]", value)  # tests/security/conftest.py records the pair
            _ATTACKS[name] = verdict


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    scheduling.longest_first(items)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """`make test`'s ``--dist loadfile``, longest modules first (tests/harness/scheduling.py)."""
    if config.getoption("dist", None) != "loadfile":
        return None
    return scheduling.make_scheduler(config, log)


def pytest_sessionfinish(session: pytest.Session) -> None:
    if not hasattr(session.config, "workerinput"):  # the controller (or a run without xdist)
        scheduling.write_recorded()


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not _ATTACKS:
        return
    tried = {k: v for k, v in _ATTACKS.items() if v != "skipped"}
    won = sorted(k for k, v in tried.items() if v.startswith("succeeded"))
    broken = sorted(k for k, v in tried.items() if v.startswith("not judged"))
    tr = terminalreporter
    tr.section("attacks")
    line = f"attacks tried {len(tried)}, succeeded {len(won)}, skipped {len(_ATTACKS) - len(tried)}"
    tr.write_line(line + (f", not judged {len(broken)}" if broken else ""))
    for name in won:
        tr.write_line(f"  SUCCEEDED: {name} ({tried[name]})")
    for name in broken:
        tr.write_line(f"  NOT JUDGED: {name} ({tried[name]})")


def _netns_reason() -> str | None:
    """`netns_reason`, by the name the SITL fixtures import it under."""
    return netns_reason()


@pytest.fixture
def netns() -> Iterator[NetNamespace]:
    """A private network namespace with multicast on lo; skips with the reason where none can be made."""
    with private_netns() as ns:
        yield ns


class Probe(JsonLinesProcess):
    """Client side of tests/children/probe.py: publish, wait for and list messages inside a namespace."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        super().__init__(proc, "the LCM probe")

    @classmethod
    def start(cls, ns: NetNamespace) -> Probe:
        """tests/children/probe.py on the namespace's multicast group, ready for requests."""
        return cls(ns.peer("tests.children.probe", MCAST_URL))

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
        msgs: list[dict[str, Any]] = self.call(op="history", channel=channel, type=type_name, since=since)[
            "msgs"
        ]
        return msgs

    def mark(self) -> int:
        return int(self.call(op="mark")["index"])


@pytest.fixture
def made() -> Iterator[list[Any]]:
    """Adapters and emulators a test made, closed (an `VehicleAdapter`) or stopped (an emulator) at the end,
    newest first, whatever happens."""
    things: list[Any] = []
    yield things
    for thing in reversed(things):
        thing.close() if isinstance(thing, VehicleAdapter) else thing.stop()


@pytest.fixture
def probe(netns: NetNamespace) -> Iterator[Probe]:
    yield Probe.start(netns)


@pytest.fixture
def launch(netns: NetNamespace, tmp_path: Path) -> Iterator[Callable[..., AgentProcesses]]:
    """Start agents as separate node processes in ``netns``; each must exit cleanly at the end.

    On multicast with no key: the probe plays an unsigned operator and behavior, so an agent runs
    insecure unless the test says otherwise (tests/core/test_security_*.py fly the signed path).
    """
    from tests.harness.agents import AgentProcesses, agent_config  # it imports this module

    started: list[AgentProcesses] = []

    def start(name: str = "alpha", nodes: tuple[str, ...] = ("hlc", "mc"), **kw: Any) -> AgentProcesses:
        kw.setdefault("security", {"insecure": True})
        agent = AgentProcesses(netns, tmp_path, agent_config(name, **kw))
        for node in nodes:
            agent.start(node)
        started.append(agent)
        return agent

    yield start
    for agent in started:
        codes = agent.stop()
        assert all(c in (0, -15, None) for c in codes.values()), f"unclean exit {codes}"
