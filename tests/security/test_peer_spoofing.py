"""Spoofed telemetry and payloads: what one agent's nodes tell each other, and what reaches the
station and the swarm behavior, forged by a host that knows no key.

* ``{agent}/TELEMETRY`` feeds the agent's OSC, which reports the position to the station (and from
  there into every peer's sector detection). alpha's OSC shares a process with its HLC; charlie's
  runs in a process of its own, so its telemetry crosses processes, signed.
* ``{agent}/OPERATOR_PAYLOAD`` and ``{agent}/DIRECTION_CMD`` feed ``dovrat_swarm``.
"""

from __future__ import annotations

import math
import time

import pytest

from antalate_lcm.base.geo import offset
from tests.harness.polling import wait_for
from tests.security.harness import HOME, PeerClient, Swarm, assert_unmoved, baseline
from tests.security.test_nonsense import PAYLOADS, still_swarming, swarming

pytestmark = pytest.mark.netns

FAR = offset(HOME[0], HOME[1], -3000.0, 4000.0)


def station_position(swarm: Swarm, operator: PeerClient, name: str) -> tuple[float, float, float]:
    r = operator.http1("GET", "/api/agents", headers=swarm.auth("read-only"))
    row = next(a for a in r["body"] if a["name"] == name)
    return row["telemetry"]["lat"], row["telemetry"]["lon"], row["last_seen"] or 0.0


@pytest.mark.parametrize("name", ["alpha", "charlie"])
@pytest.mark.attack("spoofed telemetry_t of a real agent (to its OSC, the station and the peers)")
def test_spoofed_telemetry_does_not_reach_the_station(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, name: str
) -> None:
    run = swarm.agents[name]
    home = (run.doc["hlc"]["autopilot_params"]["home_lat"], run.doc["hlc"]["autopilot_params"]["home_lon"])
    before = baseline(run)
    seen: list[tuple[float, float, float]] = []
    end = time.monotonic() + 2.0
    seq = 800_000
    while time.monotonic() < end:
        seq += 1
        attacker.publish(
            f"{name}/TELEMETRY",
            "telemetry_t",
            header={"agent": name, "seq": seq},
            lat=FAR[0],
            lon=FAR[1],
            alt=40.0,
            heading=90.0,
            battery=5.0,
            armed=True,
            in_air=True,
            mode="SPOOF",
        )
        if seq % 5 == 0:
            seen.append(station_position(swarm, operator, name))
        time.sleep(0.04)
    t = time.time()
    # What the station reported during the attack and after it: only where the vehicle really is.
    assert wait_for(lambda: station_position(swarm, operator, name)[2] > t, 10.0, 0.2), (
        f"{name} stopped reporting"
    )
    seen.append(station_position(swarm, operator, name))
    v = run.vehicle()
    real = offset(home[0], home[1], v.north, v.east)
    for lat, lon, _ in seen:
        assert math.hypot(lat - real[0], lon - real[1]) < 1e-4, (
            f"the station showed {name} at {lat:.5f}, {lon:.5f}; it is at {real[0]:.5f}, {real[1]:.5f}"
        )
    assert_unmoved(run, before, tolerance=0.5)


@pytest.mark.attack("spoofed payload_t (unsigned detections and count: Infinity) to a swarming agent")
def test_spoofed_payload_to_a_swarming_agent(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient
) -> None:
    delta = swarming(swarm, operator)
    for i in range(20):
        data = PAYLOADS[i % len(PAYLOADS)].encode()
        attacker.publish(
            "delta/OPERATOR_PAYLOAD",
            "payload_t",
            header={"agent": "delta", "seq": 700_000 + i},
            content_type="application/json",
            size=len(data),
            data=data.hex(),
        )
        time.sleep(0.02)
    still_swarming(swarm, operator, delta)


@pytest.mark.attack("spoofed direction_cmd_t (unsigned, forged MAC) to a swarming agent")
def test_spoofed_direction_to_a_swarming_agent(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient
) -> None:
    delta = swarming(swarm, operator)
    lines = len([ln for ln in delta.lines() if "operator direction:" in ln])
    for i in range(20):
        mac = {"mac_len": 32, "mac": (b"\x5a" * 32).hex()} if i % 2 else {}
        for channel, target in (("delta/DIRECTION_CMD", "delta"), ("SWARM/DIRECTION_CMD", "")):
            attacker.publish(
                channel,
                "direction_cmd_t",
                header={"agent": "operator", "seq": 710_000 + i, **mac},
                active=True,
                azimuth=float(i * 17 % 360),
                speed=4.0,
                target=target,
            )
        time.sleep(0.02)
    still_swarming(swarm, operator, delta)
    adopted = [ln for ln in delta.lines() if "operator direction:" in ln][lines:]
    assert not adopted, f"delta adopted a spoofed direction: {adopted}"
