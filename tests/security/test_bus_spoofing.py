"""Issue 13, attack 1: one datagram moves a vehicle. A spoofed ``mc_state_t`` TAKEOFF, a spoofed
``hlc_state_t`` LLC_DOWN and an injected ``velocity_cmd_t`` from a host that knows no key, on the LAN
group and on the agents' ttl=0 "local" group alike (ttl=0 only limits the sender, not who may send).

bravo and charlie run their MC and HLC as separate processes (internal topics cross processes,
signed); alpha and delta run in one ``antalate agent`` process (internal topics in-process).
"""

from __future__ import annotations

import time
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t, mc_state_t, velocity_cmd_t
from tests.security.harness import AgentRun, PeerClient, Swarm, agent_doc, assert_unmoved, baseline, fly

pytestmark = pytest.mark.netns

SPOOF_SECONDS = 1.5
RATE_HZ = 20.0


def stream(attacker: PeerClient, channel: str, type_name: str, **fields: Any) -> None:
    """Publish a freshly stamped spoof at RATE_HZ for SPOOF_SECONDS, out-shouting the genuine 5 Hz state."""
    end = time.monotonic() + SPOOF_SECONDS
    seq = 900_000
    while time.monotonic() < end:
        seq += 1
        attacker.publish(channel, type_name, header={"agent": channel.split("/", 1)[0], "seq": seq}, **fields)
        time.sleep(1.0 / RATE_HZ)


def alive(run: AgentRun) -> None:
    procs = dict(run.procs) | ({"agent process": run.shared} if run.shared is not None else {})
    for node, proc in procs.items():
        assert proc.poll() is None, f"{run.name}'s {node} died: {run.log()[-3000:]}"


@pytest.mark.attack("spoofed mc_state_t TAKEOFF, MC and HLC in separate processes")
def test_spoofed_mc_takeoff_does_not_launch_a_separate_process_hlc(
    swarm: Swarm, attacker: PeerClient
) -> None:
    bravo = swarm.agents["bravo"]
    before = baseline(bravo)
    assert not before.vehicle.armed and bravo.mc_state() == "STANDBY"
    stream(attacker, "bravo/MC_STATE", "mc_state_t", state=mc_state_t.TAKEOFF, takeoff_altitude=2.1)
    assert_unmoved(bravo, before)
    alive(bravo)


@pytest.mark.attack("spoofed mc_state_t TAKEOFF then MISSION, antalate agent (one process, with a BMA)")
def test_spoofed_mc_takeoff_does_not_launch_an_in_process_agent(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient
) -> None:
    """alpha's HLC and its swarm arbiter both follow MC_STATE: neither may hear the spoof."""
    alpha = swarm.agents["alpha"]
    before = baseline(alpha)
    assert not before.vehicle.armed and alpha.mc_state() == "STANDBY"
    mark = operator.mark()
    stream(attacker, "alpha/MC_STATE", "mc_state_t", state=mc_state_t.TAKEOFF, takeoff_altitude=2.1)
    stream(attacker, "alpha/MC_STATE", "mc_state_t", state=mc_state_t.MISSION)
    assert_unmoved(alpha, before)
    alive(alpha)
    arbiter = operator.history("alpha/ARBITER/swarm", "arbiter_status_t", since=mark, genuine=True)
    assert arbiter, "alpha's arbiter published no signed status during the attack"
    states = {(a["state"], tuple(a["active"])) for a in arbiter}
    assert states == {("STANDBY", ())}, f"alpha's swarm arbiter followed the spoof: {states}"


@pytest.mark.attack(
    "injected velocity_cmd_t north 3.2 m/s to a flying vehicle (MC and HLC in separate processes)"
)
def test_injected_velocity_does_not_move_a_flying_vehicle(
    swarm: Swarm, operator: PeerClient, attacker: PeerClient
) -> None:
    charlie = fly(swarm, operator, "charlie")
    before = baseline(charlie)
    stream(attacker, "charlie/VELOCITY_CMD", "velocity_cmd_t", frame=velocity_cmd_t.NED, vx=3.2)
    after = assert_unmoved(charlie, before, tolerance=0.5)
    assert after.in_air
    alive(charlie)


@pytest.mark.attack("injected velocity_cmd_t north 3.2 m/s to a swarming agent (antalate agent, one process)")
def test_injected_velocity_does_not_steer_a_swarming_agent(
    swarm: Swarm, operator: PeerClient, attacker: PeerClient
) -> None:
    """delta flies dovrat_swarm at 1 m/s: the attacker's 3.2 m/s must never show in its speed."""
    delta = fly(swarm, operator, "delta")
    before = baseline(delta)
    speeds: list[float] = []
    end = time.monotonic() + SPOOF_SECONDS + 1.0
    seq = 950_000
    while time.monotonic() < end:
        seq += 1
        attacker.publish(
            "delta/VELOCITY_CMD",
            "velocity_cmd_t",
            header={"agent": "delta", "seq": seq},
            frame=velocity_cmd_t.NED,
            vx=3.2,
        )
        if seq % 4 == 0:
            speeds.append(delta.vehicle().speed)
        time.sleep(1.0 / RATE_HZ)
    assert max(speeds) < 1.5, f"delta flew faster than its swarm behavior commands: {speeds}"
    assert_unmoved(delta, before, still=False)
    alive(delta)


@pytest.mark.parametrize("name", ["charlie", "delta"])
@pytest.mark.attack("spoofed hlc_state_t LLC_DOWN to the MC of a flying vehicle")
def test_spoofed_llc_down_does_not_put_the_mc_in_error(
    swarm: Swarm, operator: PeerClient, attacker: PeerClient, name: str
) -> None:
    run = fly(swarm, operator, name)
    before = baseline(run)
    stream(attacker, f"{name}/HLC_STATE", "hlc_state_t", state=hlc_state_t.LLC_DOWN, autopilot="sim")
    after = assert_unmoved(run, before, tolerance=0.5, still=name == "charlie")
    assert after.in_air and run.mc_state() == "MISSION"
    # The genuine (signed) MC state still says MISSION: what an operator console trusts.
    mark = operator.mark()
    genuine = operator.wait(f"{name}/MC_STATE", "mc_state_t", since=mark, genuine=True, timeout=5)
    assert genuine is not None, f"{name}'s MC publishes no signed mc_state_t"
    assert genuine["state"] == mc_state_t.MISSION
    alive(run)


@pytest.mark.attack("spoofed mc_state_t TAKEOFF to an HLC left on multicast without a swarm key")
def test_an_hlc_without_a_key_on_multicast_refuses_to_start(swarm: Swarm, attacker: PeerClient) -> None:
    """The defence against a swarm configured without a key: its nodes do not start, so there is no
    vehicle for a spoofed TAKEOFF to launch. (``[security] insecure = true`` accepts the risk, loudly.)"""
    doc = agent_doc("golf", swarm.tmp / "state")
    doc["security"] = {"swarm_key": ""}
    run = swarm.agent("golf", doc)
    run.start("hlc")
    proc = run.procs["hlc"]
    # Meanwhile the attacker tries to launch it, in case it did start.
    end = time.monotonic() + 10.0
    while proc.poll() is None and time.monotonic() < end:
        attacker.publish(
            "golf/MC_STATE",
            "mc_state_t",
            header={"agent": "golf", "seq": 1},
            state=mc_state_t.TAKEOFF,
            takeoff_altitude=2.1,
        )
        time.sleep(0.1)
    assert proc.poll() is not None and proc.returncode != 0, (
        f"golf's HLC runs without a key: {run.log()[-2000:]}"
    )
    log = run.log()
    assert "swarm_key" in log and "insecure" in log, log[-2000:]
    assert not run.state_file.exists(), "the sim vehicle was started"
    assert not run.transitions("hlc"), run.transitions("hlc")
