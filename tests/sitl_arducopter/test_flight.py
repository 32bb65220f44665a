"""The real ArduCopter 4.6.3 (SITL) flown by a whole agent: boot, mission, link faults, pilot, HLC restart.

One vehicle for the module (`copter`), booted with the agent already connected -- the field's order, a
companion computer and a flight controller powered up together. Each test starts from the vehicle landed,
disarmed and the MC in STANDBY, asserts what the operator sees (MC/HLC states, ``hlc_error_t`` reasons)
and what the vehicle did by its own telemetry on a second MAVLink link (`gcs`), and leaves it landed.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from tests.conftest import Probe
from tests.netns import NetNamespace
from tests.polling import wait_for
from tests.sitl_arducopter.harness import Copter

pytestmark = [pytest.mark.netns, pytest.mark.timeout(300)]
AGENT = "copter"
_seq = itertools.count(1)
TIMINGS: dict[str, float] = {}


def command(probe: Probe, cmd: int) -> None:
    probe.publish(
        f"{AGENT}/OPERATOR_CMD", "operator_cmd_t", header={"seq": next(_seq), "agent": "op"}, command=cmd
    )


def direction(probe: Probe, azimuth: float, speed: float, active: bool = True) -> None:
    probe.publish(
        f"{AGENT}/DIRECTION_CMD",
        "direction_cmd_t",
        header={"seq": next(_seq), "agent": "op"},
        active=active,
        azimuth=azimuth,
        speed=speed,
    )


def wait_state(probe: Probe, node: str, state: int, timeout: float, since: int = 0) -> dict[str, Any]:
    channel = "MC_STATE" if node == "mc" else "HLC_STATE"
    msg = probe.wait(f"{AGENT}/{channel}", f"{node}_state_t", timeout=timeout, since=since, state=state)
    assert msg is not None, f"{node} never reached {state} within {timeout} s"
    return msg


@pytest.fixture(scope="module")
def copter(sitl_netns: NetNamespace, sitl_dir: Path) -> Iterator[Copter]:
    c = Copter(sitl_netns, sitl_dir / "copter")
    yield c
    c.stop()


def test_boot_with_the_agent_connected_takes_off_as_soon_as_arducopter_allows(
    copter: Copter, sitl_probe: Probe
) -> None:
    """Issue #25: the first SYS_STATUS says the battery unhealthy (0 mV): that was latched as a battery
    failsafe and every TAKEOFF refused, "battery low", at 12.6 V. Now the TAKEOFF sent at STANDBY waits
    for the vehicle to be ready and flies; boot -> ready and TAKEOFF -> AIRBORNE are recorded."""
    probe = sitl_probe
    wait_state(probe, "mc", M.STANDBY, timeout=60)
    mark = probe.mark()
    sent = time.monotonic()
    command(probe, O.TAKEOFF)
    wait_state(probe, "mc", M.TAKEOFF, timeout=10, since=mark)
    assert wait_for(lambda: copter.gcs.state()["armed"], timeout=120, interval=0.2)
    armed = time.monotonic()
    wait_state(probe, "hlc", H.AIRBORNE, timeout=60, since=mark)
    airborne = time.monotonic()
    TIMINGS.update(boot_to_ready=armed - copter.booted_at, takeoff_to_airborne=airborne - sent)
    print(f"\nSITL timings: {TIMINGS}")
    errors = probe.history(f"{AGENT}/HLC_ERROR", "hlc_error_t", since=mark)
    assert not [e for e in errors if "battery" in e["text"]], errors
    state = copter.gcs.state()
    assert state["mode"] == "GUIDED" and state["armed"] and state["alt"] > 4.0, state
