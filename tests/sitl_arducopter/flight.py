"""The operator's side of a SITL flight test, shared by the ArduCopter and PX4 SITL modules.

Commands and directions published by the test's probe as an operator would, waits on the MC's and HLC's
states, and `landed`, which also asks the vehicle itself (`harness.Gcs`) that it is disarmed. The agent
is called `AGENT` unless a test says otherwise.
"""

from __future__ import annotations

import itertools
import time
from typing import Any

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from tests.conftest import Probe
from tests.harness.polling import wait_for
from tests.sitl_arducopter.harness import SitlVehicle

AGENT = "copter"
_seq = itertools.count(1)


def command(probe: Probe, cmd: int, agent: str = AGENT) -> None:
    probe.publish(
        f"{agent}/OPERATOR_CMD", "operator_cmd_t", header={"seq": next(_seq), "agent": "op"}, command=cmd
    )


def direction(probe: Probe, azimuth: float, speed: float, active: bool = True, agent: str = AGENT) -> None:
    probe.publish(
        f"{agent}/DIRECTION_CMD",
        "direction_cmd_t",
        header={"seq": next(_seq), "agent": "op"},
        active=active,
        azimuth=azimuth,
        speed=speed,
    )


def wait_state(
    probe: Probe, node: str, state: int, timeout: float, since: int = 0, agent: str = AGENT
) -> dict[str, Any]:
    channel = "MC_STATE" if node == "mc" else "HLC_STATE"
    msg = probe.wait(f"{agent}/{channel}", f"{node}_state_t", timeout=timeout, since=since, state=state)
    assert msg is not None, f"{agent}: {node} never reached {state} within {timeout} s"
    return msg


def errors(probe: Probe, since: int, agent: str = AGENT) -> list[str]:
    return [e["text"] for e in probe.history(f"{agent}/HLC_ERROR", "hlc_error_t", since=since)]


def hlc_states(probe: Probe, since: int, agent: str = AGENT) -> list[tuple[int, str]]:
    """The HLC's states and reasons since `since`, each change once."""
    seen: list[tuple[int, str]] = []
    for m in probe.history(f"{agent}/HLC_STATE", "hlc_state_t", since=since):
        if not seen or seen[-1][0] != m["state"]:
            seen.append((m["state"], m["reason"]))
    return seen


def take_off(vehicle: SitlVehicle, probe: Probe, timeout: float = 60) -> int:
    """From STANDBY on the ground to MISSION at 5 m (within `timeout` s); the probe mark when it got there."""
    wait_state(probe, "mc", M.STANDBY, timeout=60, since=probe.mark())
    mark = probe.mark()
    command(probe, O.TAKEOFF)
    wait_state(probe, "mc", M.MISSION, timeout=timeout, since=mark)
    wait_state(probe, "hlc", H.AIRBORNE, timeout=30, since=mark)
    return probe.mark()


def landed(vehicle: SitlVehicle, probe: Probe, since: int, timeout: float = 120) -> dict[str, Any]:
    """Wait for the MC's STANDBY with the vehicle on the ground and disarmed (its own telemetry)."""
    wait_state(probe, "mc", M.STANDBY, timeout=timeout, since=since)
    wait_state(probe, "hlc", H.READY, timeout=10, since=since)

    def disarmed() -> dict[str, Any] | None:
        state = vehicle.gcs.state()
        return None if state["armed"] else state

    state = wait_for(disarmed, timeout=15, interval=0.2)
    assert state, vehicle.gcs.state()
    return state


def fly_east(vehicle: SitlVehicle, probe: Probe, seconds: float, speed: float = 3.0) -> None:
    """The operator's direction east for `seconds` (repeated every 0.5 s, as the console does every 1 s)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        direction(probe, 90.0, speed)
        time.sleep(0.5)


def back_on_the_ground(vehicle: SitlVehicle, probe: Probe, land_mode: str = "LAND") -> None:
    """After a test the vehicle is on the ground, disarmed, the MC in STANDBY: a failed test lands it
    (the operator's LAND, else `land_mode` from the second ground station)."""
    vehicle.gcs.relay("pass")
    for node in vehicle.nodes:
        if node not in vehicle.agent.procs or not vehicle.agent.alive(node):
            vehicle.start(node)
    if vehicle.gcs.state()["armed"]:
        command(probe, O.LAND)
        if not wait_for(lambda: not vehicle.gcs.state()["armed"], timeout=60, interval=0.5):
            vehicle.gcs.ok(op="set_mode", mode=land_mode)
            wait_for(lambda: not vehicle.gcs.state()["armed"], timeout=60, interval=0.5)
    wait_state(probe, "mc", M.STANDBY, timeout=30, since=probe.mark())
