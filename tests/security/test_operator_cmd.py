"""The attacks that already held before issue 13 (keep them holding): ``operator_cmd_t`` that is
unsigned, forged, truncated, re-targeted or replayed, in bulk, at the agents on the ground.

Every datagram is a TAKEOFF (the one command that launches a vehicle from STANDBY), sent both to an
agent's own channel and to the broadcast ``SWARM/OPERATOR_CMD`` that every MC listens to.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import time

import pytest

from antalate_lcm.msgs import operator_cmd_t
from tests.security.harness import (
    OPERATOR,
    WINDOW,
    AgentRun,
    Baseline,
    PeerClient,
    Swarm,
    assert_unmoved,
    baseline,
)

pytestmark = pytest.mark.netns

GROUND = ("alpha", "bravo")
CHANNELS = ("bravo/OPERATOR_CMD", "alpha/OPERATOR_CMD", "SWARM/OPERATOR_CMD")
N = 100  # per channel: 300 datagrams per category
GAP = 0.002  # s between datagrams: what a receiver's socket keeps up with


def takeoff(target: str, seq: int, utime: int | None = None) -> operator_cmd_t:
    msg = operator_cmd_t()
    msg.header.utime = utime if utime is not None else int(time.time() * 1e6)
    msg.header.agent = OPERATOR
    msg.header.seq = seq
    msg.command = operator_cmd_t.TAKEOFF
    msg.target = target
    msg.altitude = 2.1
    return msg


def with_mac(msg: operator_cmd_t, mac: bytes) -> bytes:
    msg.header.mac_len, msg.header.mac = len(mac), mac
    return msg.encode()


def before(swarm: Swarm) -> dict[str, Baseline]:
    runs = [swarm.agents[n] for n in GROUND]
    for run in runs:
        assert run.mc_state() == "STANDBY", f"{run.name} is not on the ground in STANDBY"
    return {run.name: baseline(run) for run in runs}


def after(swarm: Swarm, marks: dict[str, Baseline], operator: PeerClient) -> None:
    time.sleep(1.0)  # what a launch would need to show, for every agent at once
    for name, mark in marks.items():
        run: AgentRun = swarm.agents[name]
        assert_unmoved(run, mark, wait=0.0)
    # The MCs still run and acknowledge nothing new: their genuine state carries no attacker seq.
    since = operator.mark()
    for name in GROUND:
        genuine = operator.wait(f"{name}/MC_STATE", "mc_state_t", since=since, genuine=True, timeout=5)
        assert genuine is not None, f"{name}'s MC publishes no signed mc_state_t"
        assert genuine["last_command_seq"] < 500_000, genuine


def targets(channel: str) -> str:
    return "" if channel.startswith("SWARM/") else channel.split("/", 1)[0]


@pytest.mark.attack("unsigned operator_cmd_t TAKEOFF x300")
def test_unsigned_commands(swarm: Swarm, attacker: PeerClient, operator: PeerClient) -> None:
    marks = before(swarm)
    items = [(ch, takeoff(targets(ch), 500_000 + i).encode()) for i in range(N) for ch in CHANNELS]
    attacker.batch(items, gap=GAP)
    after(swarm, marks, operator)


@pytest.mark.attack("forged operator_cmd_t TAKEOFF x300 (random MACs, another swarm's key, bad lengths)")
def test_forged_commands(swarm: Swarm, attacker: PeerClient, operator: PeerClient) -> None:
    marks = before(swarm)
    items = []
    for i in range(N):
        for ch in CHANNELS:
            msg = takeoff(targets(ch), 600_000 + i)
            kind = i % 4
            if kind == 0:
                mac = os.urandom(32)
            elif kind == 1:  # a valid HMAC, under a key the attacker made up
                msg.header.mac_len, msg.header.mac = 0, b""
                mac = hmac.new(b"guessed-swarm-key", msg.encode(), hashlib.sha256).digest()
            elif kind == 2:
                mac = os.urandom(16)
            else:
                mac = b"\x00" * 32
            items.append((ch, with_mac(msg, mac)))
    attacker.batch(items, gap=GAP)
    after(swarm, marks, operator)


def recorded_genuine(
    swarm: Swarm, operator: PeerClient, attacker: PeerClient, target: str, utime: int | None = None
) -> bytes:
    """A genuine signed TAKEOFF the operator sent to ``target``, as the attacker recorded it off the
    network. Fresh ones go to an agent that does not exist, so sending them moved nothing."""
    channel = f"{target or 'SWARM'}/OPERATOR_CMD"
    mark = attacker.mark()
    header: dict[str, object] = {"agent": OPERATOR, "seq": swarm.next_seq()}
    if utime is not None:
        header["utime"] = utime
    operator.publish(
        channel,
        "operator_cmd_t",
        sign=True,
        stamp=utime is None,
        header=header,
        command=operator_cmd_t.TAKEOFF,
        target=target,
        altitude=2.1,
    )
    assert attacker.wait(channel, "operator_cmd_t", since=mark, timeout=5) is not None
    return attacker.capture(channel, "operator_cmd_t", since=mark)


@pytest.mark.attack("truncated genuine operator_cmd_t x300 (datagram cut short, MAC cut short)")
def test_truncated_commands(swarm: Swarm, attacker: PeerClient, operator: PeerClient) -> None:
    """Cut-short datagrams do not even decode (the node must survive them); a MAC cut short inside a
    well-formed message does decode, and must not pass for a signature."""
    marks = before(swarm)
    old = int((time.time() - 3 * WINDOW) * 1e6)  # recorded a while ago
    items = []
    for target in GROUND:
        genuine = recorded_genuine(swarm, operator, attacker, target, utime=old)
        channel = f"{target}/OPERATOR_CMD"
        items += [(channel, genuine[:n]) for n in range(1, len(genuine))]
        for n in range(32):
            msg = operator_cmd_t.decode(genuine)
            msg.header.utime = int(time.time() * 1e6)  # fresh again: the cut MAC is all that stops it
            items.append((channel, with_mac(msg, bytes(msg.header.mac)[:n])))
    attacker.batch(items, gap=GAP)
    after(swarm, marks, operator)


@pytest.mark.attack("re-targeted genuine operator_cmd_t x300 (target rewritten, or sent on another channel)")
def test_retargeted_commands(swarm: Swarm, attacker: PeerClient, operator: PeerClient) -> None:
    marks = before(swarm)
    genuine = recorded_genuine(swarm, operator, attacker, "zulu")
    items = []
    for ch in CHANNELS:
        items.append((ch, genuine))  # as signed (target "zulu"), on a ground agent's channel
        msg = operator_cmd_t.decode(genuine)
        msg.target = targets(ch)  # rewritten to the channel's agent (or "" = everyone), MAC kept
        items.append((ch, msg.encode()))
    attacker.batch(items * (N // 2), gap=GAP)
    after(swarm, marks, operator)


@pytest.mark.attack("replayed genuine operator_cmd_t x300, recorded long ago (outside the window)")
def test_replayed_stale_commands(swarm: Swarm, attacker: PeerClient, operator: PeerClient) -> None:
    marks = before(swarm)
    old = int((time.time() - 3 * WINDOW) * 1e6)
    items = []
    for target in GROUND:
        genuine = recorded_genuine(swarm, operator, attacker, target, utime=old)
        items += [(f"{target}/OPERATOR_CMD", genuine), ("SWARM/OPERATOR_CMD", genuine)]
    genuine = recorded_genuine(swarm, operator, attacker, "", utime=old)
    items.append(("SWARM/OPERATOR_CMD", genuine))
    attacker.batch(items * (3 * N // len(items)), gap=GAP)
    after(swarm, marks, operator)
