"""The admission pipeline's own entry points (antalate_lcm/core/admission.py): what the OSC relays for
an operator (`Node.relay`, `NodeAdmission.vet_relay`), the console's datagram check, and a watcher's
exposure. The attacks through real processes are tests/security/; these pin the order of the checks."""

from __future__ import annotations

import time
from typing import Any

import pytest

from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, InsecureBus, Node, NodeSettings
from antalate_lcm.msgs import operator_cmd_t
from antalate_lcm.wire.security import Reason, sign, signed_bytes
from antalate_lcm.wire.vocabulary import Command

KEY = "admission test key"
UDPM = "udpm://239.255.76.67:7667?ttl=0"


def _settings(name: str = "a-1", **security: Any) -> NodeSettings:
    config = parse_config(
        {"agent": {"name": name}, "buses": {"lan": UDPM}, "security": security}, "agent.toml"
    )
    return NodeSettings.from_config(config)


def _command(
    target: str, *, key: str = "", utime: float | None = None, altitude: float = 5.0
) -> operator_cmd_t:
    msg = operator_cmd_t()
    msg.command = int(Command.TAKEOFF)
    msg.target = target
    msg.altitude = altitude
    msg.header.agent = "operator"
    msg.header.seq = 7
    msg.header.utime = int((time.time() if utime is None else utime) * 1_000_000)
    if key:
        sign(msg, key)
    return msg


@pytest.fixture
def context() -> Any:
    ctx = Context(Buses({"lan": UDPM}), Executor())  # never opened: nothing here sends
    yield ctx
    ctx.close()


def test_relay_checks_target_then_signature_then_fields(context: Context) -> None:
    vet = Node(_settings(swarm_key=KEY), context, name="osc").admission.vet_relay
    channel = "a-1/OPERATOR_CMD"
    # Signed for another agent: refused before any MAC is computed (and not counted as forged).
    refused = vet(_command("a-2", key=KEY), signed=True, channel=channel)
    assert refused is not None and refused.reason == "retargeted" and not refused.logged
    # Signed with another key: the authenticator refuses (and logs) it.
    refused = vet(_command("a-1", key="another key"), signed=True, channel=channel)
    assert refused is not None and refused.reason == Reason.FORGED.value and refused.logged
    # Too old for the window.
    refused = vet(_command("", key=KEY, utime=time.time() - 60), signed=True, channel=channel)
    assert refused is not None and refused.reason == Reason.STALE.value
    # Authentic but nonsense: validation refuses it.
    refused = vet(_command("a-1", key=KEY, altitude=float("nan")), signed=True, channel=channel)
    assert refused is not None and refused.reason == "invalid" and not refused.logged
    # Authentic and sound, then the same message again: a replay.
    good = _command("a-1", key=KEY)
    assert vet(good, signed=True, channel=channel) is None
    again = operator_cmd_t.decode(good.encode())
    refused = vet(again, signed=True, channel=channel)
    assert refused is not None and refused.reason == Reason.REPLAYED.value
    # Unsigned, with a key: never.
    refused = vet(_command("a-1"), signed=False, channel=channel)
    assert refused is not None and refused.reason == "unsigned"


def test_a_keyless_agent_relays_unsigned_commands_only_when_valid(context: Context) -> None:
    vet = Node(_settings(), context, name="osc").admission.vet_relay
    assert vet(_command("a-1"), signed=False, channel="a-1/OPERATOR_CMD") is None
    refused = vet(_command("a-1", altitude=-3.0), signed=False, channel="a-1/OPERATOR_CMD")
    assert refused is not None and refused.reason == "invalid"


def test_the_console_check_verifies_the_datagram_with_the_nodes_keys(context: Context) -> None:
    keyed = Node(_settings("console", swarm_key=KEY, previous_keys=["old key"]), context, watcher=True)
    msg = _command("")
    now = msg.header.utime / 1e6
    assert keyed.admission.checks_datagrams
    assert keyed.admission.check_datagram(signed_bytes(msg, KEY), now) is None
    assert keyed.admission.check_datagram(signed_bytes(msg, "old key"), now) is None
    forged = keyed.admission.check_datagram(signed_bytes(msg, "another key"), now)
    assert forged is not None and forged.reason is Reason.FORGED
    stale = keyed.admission.check_datagram(signed_bytes(msg, KEY), now + 60)
    assert stale is not None and stale.reason is Reason.STALE
    keyless = Node(_settings("console"), context, watcher=True)
    assert not keyless.admission.checks_datagrams
    assert keyless.admission.check_datagram(b"anything", now) is None


def test_only_a_watcher_may_read_internal_topics_from_the_network_without_a_key(context: Context) -> None:
    Node(_settings("console"), context, watcher=True).admission.check_exposure(
        "MC_STATE", "lan"
    )  # no refusal
    with pytest.raises(InsecureBus):
        Node(_settings("a-1"), context).admission.check_exposure("MC_STATE", "lan")


def test_outgoing_is_the_contexts_scratch_only_for_a_node_that_neither_signs_nor_is_interfered(
    context: Context,
) -> None:
    """`Node.outgoing` reads the node's own `_scratch`: the same answer as asking its admission and
    interference, as before, for a plain node, a signing one and one an experiment interferes with."""

    def before(node: Node) -> bool:  # the path it replaces: whether the context's scratch is used
        return node.interference is None and not node.admission.signs

    plain, signing = Node(_settings(), context), Node(_settings(swarm_key=KEY), context, name="s")
    interfered = Node(_settings(name="a-2"), context)
    interfered.interference = object()  # type: ignore[assignment]  # set before start, as the runs do
    for node in (plain, signing, interfered):
        first, second = node.outgoing(operator_cmd_t), node.outgoing(operator_cmd_t)
        shared = first is second
        assert shared is before(node) is (node is plain)
        assert (first is context.scratch.get(operator_cmd_t)) is shared
