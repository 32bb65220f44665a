"""Issue 13, attack 4: signed nonsense. A valid MAC proves who sent a message, not that its numbers
make sense: a payload with ``count: Infinity`` or a direction with an infinite azimuth killed
``dovrat_swarm`` for the rest of the mission; a TAKEOFF altitude of Infinity/NaN must not launch.

These messages are signed with the swarm key, as a buggy (or compromised) keyed node would send them.
delta flies ``dovrat_swarm`` (1 m/s forward, turning): after the attack its behavior must still be
active, not failed, and the vehicle still flying the algorithm.
"""

from __future__ import annotations

import math
import statistics
import time
from typing import Any

import pytest

from antalate_lcm.msgs import operator_cmd_t
from tests.security.harness import (
    OPERATOR,
    AgentRun,
    PeerClient,
    Swarm,
    assert_unmoved,
    baseline,
    fly,
)

pytestmark = pytest.mark.netns

BEHAVIOR = "dovrat_swarm"


def swarming(swarm: Swarm, operator: PeerClient) -> AgentRun:
    """delta in MISSION with its swarm behavior active (genuine, signed arbiter status)."""
    fly(swarm, operator, "delta")
    status = operator.wait(
        "delta/ARBITER/swarm", "arbiter_status_t", genuine=True, timeout=15, since=operator.mark()
    )
    assert status is not None, "delta's arbiter publishes no signed arbiter_status_t"
    assert BEHAVIOR in status["active"], status
    return swarm.agents["delta"]


def still_swarming(swarm: Swarm, operator: PeerClient, delta: AgentRun) -> None:
    """The behavior survived: active, not failed, nothing in the log, and the vehicle still moves."""
    time.sleep(1.0)
    since = operator.mark()
    status = operator.wait("delta/ARBITER/swarm", "arbiter_status_t", genuine=True, timeout=5, since=since)
    assert status is not None, "delta's arbiter stopped publishing"
    assert BEHAVIOR in status["active"] and not status["failed"], f"{BEHAVIOR} was killed: {status}"
    assert "failed and is deactivated" not in "\n".join(delta.lines()), "a behavior of delta failed"
    # Still flying the algorithm (1 m/s): the median ground speed over 2 s, so that one late
    # behavior tick on a loaded machine (the HLC hovers after 0.5 s without a command) does not count,
    # while a dead behavior's vehicle has all but stopped within half a second.
    speeds = []
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        v = delta.vehicle()
        assert v.in_air, f"delta is not flying: {v}"
        speeds.append(v.speed)
        time.sleep(0.2)
    assert statistics.median(speeds) > 0.5, f"delta stopped flying the swarm algorithm: speeds {speeds}"
    assert delta.mc_state() == "MISSION", delta.transitions("mc")


def signed(operator: PeerClient, swarm: Swarm, channel: str, type_name: str, **fields: Any) -> None:
    operator.publish(
        channel, type_name, sign=True, header={"agent": OPERATOR, "seq": swarm.next_seq()}, **fields
    )


PAYLOADS = [
    '{"detected": true, "count": Infinity, "nearest_range": 10.0, "nearest_bearing": 0.0}',
    '{"detected": true, "count": 1e999, "nearest_range": 10.0, "nearest_bearing": 0.0}',
    '{"detected": true, "count": NaN, "nearest_range": 10.0, "nearest_bearing": 0.0}',
    '{"detected": true, "count": 2, "nearest_range": -Infinity, "nearest_bearing": NaN}',
    '{"detected": true, "count": 100000000000000000000000000000, "nearest_range": 1e999}',
    '{"detected": true, "count": "3", "nearest_range": [], "nearest_bearing": {}}',
]


@pytest.mark.attack("signed payload_t with count: Infinity (and NaN, 1e999, wrong types) to a swarming agent")
def test_signed_nonsense_payload_does_not_kill_the_behavior(swarm: Swarm, operator: PeerClient) -> None:
    delta = swarming(swarm, operator)
    for text in PAYLOADS:
        data = text.encode()
        signed(
            operator,
            swarm,
            "delta/OPERATOR_PAYLOAD",
            "payload_t",
            content_type="application/json",
            size=len(data),
            data=data.hex(),
        )
        time.sleep(0.05)
    still_swarming(swarm, operator, delta)


@pytest.mark.attack(
    "signed direction_cmd_t with an infinite azimuth (and NaN, huge speed) to a swarming agent"
)
def test_signed_nonsense_direction_does_not_kill_the_behavior(swarm: Swarm, operator: PeerClient) -> None:
    delta = swarming(swarm, operator)
    for az, speed in (
        (math.inf, 1.0),
        (-math.inf, 1.0),
        (math.nan, 1.0),
        (90.0, math.inf),
        (90.0, math.nan),
        (1e30, 1.0),
        (90.0, 1e30),
    ):
        for channel in ("delta/DIRECTION_CMD", "SWARM/DIRECTION_CMD"):
            signed(
                operator,
                swarm,
                channel,
                "direction_cmd_t",
                active=True,
                azimuth=az,
                speed=speed,
                target="delta" if channel.startswith("delta") else "",
            )
        time.sleep(0.05)
    still_swarming(swarm, operator, delta)
    bad = [ln for ln in delta.lines() if "operator direction:" in ln and ("inf" in ln or "nan" in ln)]
    assert not bad, f"delta adopted a non-finite direction: {bad}"


@pytest.mark.attack("signed TAKEOFF with altitude Infinity/NaN/-1/1e30")
def test_signed_takeoff_with_nonsense_altitude_does_not_launch(swarm: Swarm, operator: PeerClient) -> None:
    bravo = swarm.agents["bravo"]
    assert bravo.mc_state() == "STANDBY"
    before = baseline(bravo)
    for alt in (math.inf, math.nan, -math.inf, -1.0, 1e30):
        signed(
            operator,
            swarm,
            "bravo/OPERATOR_CMD",
            "operator_cmd_t",
            command=operator_cmd_t.TAKEOFF,
            target="bravo",
            altitude=alt,
        )
        time.sleep(0.05)
    assert_unmoved(bravo, before)
