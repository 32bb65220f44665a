"""Three real ArduCopter 4.6.3 SITL instances (``--instance 0..2``, ``--sysid 1..3``) flown as one swarm by
three agents running ``dovrat_swarm``, in one network namespace on one LCM bus.

What the operator sees for each agent (MC STANDBY -> MISSION -> RTL -> STANDBY, HLC AIRBORNE -> RTL ->
READY, no ``hlc_error_t``), and what each vehicle did by its own telemetry: each is its own MAVLink
system, flies the swarm rule (forward along its heading, turning), and comes home to its own take-off
point. One boot for the module (three copters need ~40-60 s to be ready together on 2 cores).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import pytest

from antalate_lcm.base import geo
from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from tests.conftest import Probe
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.sitl_arducopter.flight import command, wait_state
from tests.sitl_arducopter.harness import HOME, Copter, one_sitl_swarm_at_a_time

pytestmark = [pytest.mark.netns, pytest.mark.timeout(400)]
NAMES = ("copter1", "copter2", "copter3")
SPACING = 6.0  # m east between the homes


def home(i: int) -> tuple[float, float, float, float]:
    lat, lon = geo.offset(HOME[0], HOME[1], 0.0, SPACING * i)
    return (lat, lon, HOME[2], HOME[3])


def has_home(copter: Copter) -> bool:
    return bool(copter.gcs.state()["home"])


def disarmed(copter: Copter) -> bool:
    return not copter.gcs.state()["armed"]


@pytest.fixture(scope="module", autouse=True)
def _one_sitl_swarm_at_a_time() -> Iterator[None]:
    """Before the vehicles boot (autouse fixtures come first in their scope)."""
    with one_sitl_swarm_at_a_time():
        yield


@pytest.fixture(scope="module")
def swarm(sitl_netns: NetNamespace, sitl_dir: Path) -> Iterator[list[Copter]]:
    bma = [
        {
            "name": "mission",
            "behaviors": [
                {
                    "plugin": "dovrat_swarm",
                    "activate_on": ["MISSION"],
                    "params": {"forward_speed": 1.5, "sharp_turn_rate": 20.0},
                }
            ],
        }
    ]
    copters: list[Copter] = []
    try:
        for i, name in enumerate(NAMES):
            copters.append(Copter(sitl_netns, sitl_dir / name, instance=i, name=name, bma=bma, home=home(i)))
        for c in copters:
            c.gcs.set_param("LAND_SPEED", 150)
            c.gcs.set_param("RTL_ALT", 800)  # cm: a shorter climb before the return
        yield copters
    finally:
        for c in copters:
            c.stop()


def test_three_sitl_copters_fly_dovrat_swarm_and_come_home(swarm: list[Copter], sitl_probe: Probe) -> None:
    probe = sitl_probe
    start = probe.mark()
    for name in NAMES:
        wait_state(probe, "mc", agent=name, state=M.STANDBY, timeout=120, since=0)
    for c in swarm:  # three MAVLink systems, one each
        assert wait_for(partial(has_home, c), timeout=60, interval=0.5), c.name
    sent = time.monotonic()
    for name in NAMES:
        command(probe, O.TAKEOFF, agent=name)
    for c in swarm:
        with c.explained():
            wait_state(probe, "mc", agent=c.name, state=M.MISSION, timeout=180, since=start)
            wait_state(probe, "hlc", agent=c.name, state=H.AIRBORNE, timeout=60, since=start)
    print(f"\nswarm: all three AIRBORNE {time.monotonic() - sent:.1f} s after TAKEOFF")
    begin = [c.gcs.state() for c in swarm]
    time.sleep(8.0)  # dovrat_swarm flies them: forward along the heading, turning without a peer ahead
    moved = [c.gcs.state() for c in swarm]
    for c, a, b in zip(swarm, begin, moved, strict=True):
        assert b["mode"] == "GUIDED" and b["armed"] and b["alt"] > 4.0, (c.name, b)
        assert math.hypot(b["north"] - a["north"], b["east"] - a["east"]) > 4.0, (c.name, a, b)
    mark = probe.mark()
    for name in NAMES:
        command(probe, O.RTL, agent=name)
    for name in NAMES:
        wait_state(probe, "mc", agent=name, state=M.RTL, timeout=15, since=mark)
    for c in swarm:
        with c.explained():
            wait_state(probe, "mc", agent=c.name, state=M.STANDBY, timeout=120, since=mark)
            wait_state(probe, "hlc", agent=c.name, state=H.READY, timeout=15, since=mark)
    for c in swarm:
        assert wait_for(partial(disarmed, c), timeout=20, interval=0.3), c.name
        down = c.gcs.state()
        assert abs(down["north"]) < 2.0 and abs(down["east"]) < 2.0, (c.name, down)  # its own home
    for name in NAMES:
        assert probe.history(f"{name}/HLC_ERROR", "hlc_error_t", since=start) == [], name
