"""Issue 13, attack 3: replays inside the window. A command accepted before an MC restart, replayed
after it; an older direction replayed after a newer one (it rolled the direction back).

The attacker records genuine signed datagrams off the network and resends them byte for byte.
"""

from __future__ import annotations

import re
import time

import pytest

from tests.harness.polling import wait_for
from tests.security.harness import (
    PeerClient,
    Swarm,
    assert_unmoved,
    baseline,
    command,
    direction,
    fly,
)

pytestmark = pytest.mark.netns


@pytest.mark.attack("genuine TAKEOFF replayed after an MC restart")
def test_command_replayed_after_mc_restart(swarm: Swarm, operator: PeerClient, attacker: PeerClient) -> None:
    bravo = swarm.agents["bravo"]
    assert bravo.mc_state() == "STANDBY"
    mark = attacker.mark()
    fly(swarm, operator, "bravo")  # a genuine TAKEOFF, which the attacker records
    n = len(bravo.transitions("mc"))
    command(operator, swarm, "bravo", "RTL")
    bravo.wait_mc("STANDBY", timeout=30, after=n)
    assert wait_for(lambda: not bravo.vehicle().armed, 15.0, 0.1), "bravo did not disarm after RTL"
    # The MC restarts (a crash, an update): whatever it remembered in memory is gone.
    bravo.kill("mc")
    n = len(bravo.transitions("mc"))
    bravo.start("mc")
    bravo.wait_mc("STANDBY", timeout=30, after=n)
    before = baseline(bravo)
    attacker.replay(
        "bravo/OPERATOR_CMD", "operator_cmd_t", pick="last", since=mark, command=0, target="bravo"
    )
    assert_unmoved(bravo, before)


DIRECTION_LINE = re.compile(r"operator direction: (\d+) deg")


def directions(swarm: Swarm, name: str) -> list[int]:
    return [int(m.group(1)) for ln in swarm.agents[name].lines() if (m := DIRECTION_LINE.search(ln))]


@pytest.mark.attack("older direction_cmd_t replayed after a newer one")
def test_older_direction_replayed(swarm: Swarm, operator: PeerClient, attacker: PeerClient) -> None:
    alpha = swarm.agents["alpha"]
    start = len(directions(swarm, "alpha"))
    mark = attacker.mark()
    direction(operator, swarm, "alpha", 90.0, 1.0)
    assert wait_for(lambda: directions(swarm, "alpha")[start:] == [90], 10.0, 0.1), directions(swarm, "alpha")
    direction(operator, swarm, "alpha", 180.0, 1.0)
    assert wait_for(lambda: directions(swarm, "alpha")[start:] == [90, 180], 10.0, 0.1), directions(
        swarm, "alpha"
    )
    before = baseline(alpha)
    for _ in range(5):
        attacker.replay("alpha/DIRECTION_CMD", "direction_cmd_t", pick="first", since=mark, azimuth=90.0)
        time.sleep(0.1)
    assert_unmoved(alpha, before)
    assert directions(swarm, "alpha")[start:] == [90, 180], (
        "the replayed direction rolled alpha's direction back"
    )
