"""The attacker suite (issue 13): one shared swarm for the session, and the tally of attacks tried.

Every test is one attack, tagged ``@pytest.mark.attack("name")``; it passes only when the attack
failed *and* nothing moved. The terminal summary counts them (tests/conftest.py): ``attacks tried N,
succeeded M`` (a failed test, or an xfail, is an attack that succeeded).
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from typing import Any

import pluggy
import pytest

from antalate_lcm.base.geo import offset
from tests.conftest import ATTACK_PROPERTY
from tests.harness.netns import NetNamespace, require_netns
from tests.harness.polling import wait_for
from tests.security.harness import HOME, SWARM_KEY, PeerClient, Swarm, agent_doc


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "attack(name): the attack a security test tries (tests/security)")


def _attack(item: pytest.Item) -> str | None:
    """The attack's name, with the parameters of a parametrized test (each is an attack of its own)."""
    mark = item.get_closest_marker("attack")
    if mark is None:
        return None
    callspec = getattr(item, "callspec", None)
    return f"{mark.args[0]} [{callspec.id}]" if callspec is not None else str(mark.args[0])


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pluggy.Result[pytest.TestReport], None]:
    """Judge the attack where the test ran and attach the verdict to the report (``user_properties``
    travel with it to the process that prints the summary: tests/conftest.py, also under xdist)."""
    outcome = yield
    report = outcome.get_result()
    name = _attack(item)
    if name is None:
        return
    if report.when == "call" or (report.when == "setup" and not report.passed):
        if hasattr(report, "wasxfail"):
            verdict = "succeeded (defence missing, xfail)"
        elif report.passed:
            verdict = "held"
        elif report.skipped:
            verdict = "skipped"
        elif call.excinfo is not None and not call.excinfo.errisinstance(AssertionError):
            verdict = f"not judged ({call.excinfo.typename})"
        else:
            verdict = "succeeded"
        report.user_properties.append((ATTACK_PROPERTY, (name, verdict)))


@pytest.fixture(scope="package")
def swarm(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Swarm]:
    """The station, four agents and the two peers, started once for the whole directory (package scope: gone when its last test ends).

    * ``alpha`` and ``delta``: one ``antalate agent`` process, OSC reporting to the station,
      ``dovrat_swarm`` on MISSION; alpha stays on the ground (the station attacks' target), the
      tests fly delta.
    * ``bravo`` and ``charlie``: MC and HLC as separate processes, so their internal topics cross
      processes on the (host-only, ttl=0) ``local`` bus, signed. bravo stays on the ground, charlie
      is flown; charlie's OSC is a third process of its own.
    """
    require_netns()
    tmp = tmp_path_factory.mktemp("security")
    ns = NetNamespace().__enter__()
    s = Swarm(ns, tmp)
    try:
        s.start_station()
        osc = {
            "enabled": True,
            "server": s.station_url,
            "rate": 5.0,
            **({"ca_file": str(s.tls[0])} if s.tls else {}),
        }
        bma = [
            {
                "name": "swarm",
                "behaviors": [
                    {
                        "plugin": "dovrat_swarm",
                        "activate_on": ["MISSION"],
                        "params": {"forward_speed": 1.0, "detection_source": "any"},
                    }
                ],
            }
        ]
        for name, north in (("alpha", 0.0), ("delta", 40.0)):
            token_file = str(tmp / f"{name}.token")
            s.agent(
                name,
                agent_doc(
                    name, tmp / "state", home=_home(north), osc={**osc, "token_file": token_file}, bma=bma
                ),
            )
        s.start_agents_process("alpha-delta", ["alpha", "delta"])
        for name, north in (("bravo", 80.0), ("charlie", 120.0)):
            extra: dict[str, Any] = (
                {"osc": {**osc, "token_file": str(tmp / f"{name}.token")}} if name == "charlie" else {}
            )
            run = s.agent(name, agent_doc(name, tmp / "state", home=_home(north), **extra))
            run.start("hlc")
            run.start("mc")
            if extra:
                run.start("osc")  # an OSC in its own process: telemetry reaches it across processes, signed
        # The attacker is another host as far as the station can tell (its own source address).
        s.attacker = s.peer("the attacker", None, source="127.0.0.2")
        s.operator = s.peer("the operator", SWARM_KEY, ca=s.tls[0] if s.tls else None)
        for run in s.agents.values():
            run.wait_mc("STANDBY", timeout=60)

        def registered() -> bool:
            r = s.operator.http1("GET", "/api/agents", headers=s.auth("read-only"))  # type: ignore[union-attr]
            return r["status"] == 200 and {a["name"] for a in r["body"]} >= {"alpha", "delta", "charlie"}

        assert wait_for(registered, 30.0, 0.2), f"the OSCs did not register: {s.station_text()[-2000:]}"
        yield s
    finally:
        s.close()


def _home(north_m: float) -> tuple[float, float]:
    return offset(HOME[0], HOME[1], north_m, 0.0)


@pytest.fixture(scope="package")
def attacker(swarm: Swarm) -> PeerClient:
    assert swarm.attacker is not None
    return swarm.attacker


@pytest.fixture(scope="package")
def operator(swarm: Swarm) -> PeerClient:
    assert swarm.operator is not None
    return swarm.operator
