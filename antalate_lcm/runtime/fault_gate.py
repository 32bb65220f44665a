"""The gate every simulated agent's messages go through while an experiment's script interferes
(:mod:`antalate_lcm.runtime.faults`): what a node sends, what it consumes, whether its timers run, and
the broadcasts each agent hears (:class:`BroadcastReception`). The :class:`FaultGate` holds what is
active now; the :class:`~antalate_lcm.runtime.faults.FaultInjector` starts and ends it on the schedule.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from antalate_lcm.base.geo import offset as geo_offset
from antalate_lcm.base.geo import wrap_180
from antalate_lcm.base.ratelimit import TokenBucket
from antalate_lcm.core.node import Node
from antalate_lcm.msgs import mc_state_t, peer_scan_t, telemetry_t
from antalate_lcm.runtime.script import FaultStep, Script
from antalate_lcm.wire.topics import OPERATOR_INPUTS, Message
from antalate_lcm.wire.vocabulary import McState

#: The broadcast control topics (one message reaches every agent) whose reception is lossy.
BROADCAST_TOPICS = frozenset({"SWARM_OPERATOR_CMD", "SWARM_DIRECTION_CMD"})
#: Broadcast decisions an agent remembers, so its nodes that consume one message agree on it.
_REMEMBERED = 256


class BroadcastReception:
    """Whether one agent hears one broadcast message: a Bernoulli(``probability``) draw from this
    agent's own stream seeded by (``seed``, agent), so reception is independent across agents and
    messages, and a run with the same seed and the same messages hears the same ones.

    A message is keyed by its channel, sender, seq and time (a resent command carries its seq and a
    fresh time: another chance); every node of the agent that consumes it gets the same answer.
    """

    def __init__(self, probability: float, seed: int, agent: str) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"reception probability in [0, 1], got {probability!r}")
        self.probability = probability
        self._rng = random.Random(f"broadcast/{seed}/{agent}")
        self._decided: dict[tuple[str, str, int, int], bool] = {}
        #: Distinct broadcast messages this agent was offered, and those it heard.
        self.offered = 0
        self.heard = 0

    def admit(self, key: tuple[str, str, int, int]) -> bool:
        got = self._decided.get(key)
        if got is None:
            got = self._rng.random() < self.probability
            self._decided[key] = got
            if len(self._decided) > _REMEMBERED:
                del self._decided[next(iter(self._decided))]
            self.offered += 1
            self.heard += got
        return got


@dataclass
class _Active:
    """A fault that has started and not ended, with what it needs while it lasts."""

    step: FaultStep
    index: int
    agent: str
    rng: random.Random
    #: A stuck sensor's reading, captured from the first message after the start.
    stuck: Message | None = None
    #: A bandwidth cap's token buckets (keys "out" and "in": each way has its own).
    bucket: TokenBucket | None = None

    def over_cap(self, way: str, size: int, now: float) -> bool:
        """Whether ``size`` bytes more exceed the cap this way now (they are lost then)."""
        return self.bucket is not None and self.bucket.take(way, now, float(size)) > 0.0


@dataclass
class FaultGate:
    """The :class:`~antalate_lcm.core.node.Interference` of every simulated agent of one experiment:
    what is active now, per agent (set by the :class:`FaultInjector` on the executor thread)."""

    broadcast: dict[str, BroadcastReception] = field(default_factory=dict)
    #: agent -> active faults, by kind
    active: dict[str, dict[str, list[_Active]]] = field(default_factory=dict)
    #: A byzantine agent's honest messages, by (agent, channel, seq, utime) of the lie sent instead.
    _truth: dict[tuple[str, str, int, int], Message] = field(default_factory=dict)

    def _of(self, agent: str, kind: str) -> list[_Active]:
        kinds = self.active.get(agent)
        return kinds.get(kind, []) if kinds else []

    def silenced(self, agent: str) -> bool:
        kinds = self.active.get(agent)
        return kinds is not None and bool(kinds.get("crash") or kinds.get("freeze"))

    def activate(self, step: FaultStep, index: int, agent: str, seed: int) -> None:
        """Fault ``index`` of the script holds ``agent`` from now on (its losses drawn from a stream
        seeded by (seed, fault, agent))."""
        rng = random.Random(f"packets/{seed}/{index}/{agent}")
        bucket = None
        if step.bandwidth is not None:
            bucket = TokenBucket(step.bandwidth, step.burst if step.burst is not None else step.bandwidth)
        active = _Active(step, index, agent, rng, bucket=bucket)
        self.active.setdefault(agent, {}).setdefault(step.kind, []).append(active)

    def deactivate(self, step: FaultStep, index: int, agent: str) -> None:
        kinds = self.active.get(agent, {})
        kinds[step.kind] = [a for a in kinds.get(step.kind, []) if a.index != index]
        if not kinds[step.kind]:
            del kinds[step.kind]
        if not kinds:
            self.active.pop(agent, None)

    def link_lost(self, agent: str) -> bool:
        return bool(self._of(agent, "link_loss"))

    # --------------------------------------------------------------------- sending
    def send(self, node: Node, topic: str, msg: Message, buses: list[str], channel: str) -> bool:
        agent = node.agent
        bus = node.context.buses
        if _watches(node) or not self.active.get(agent):
            data = node.admission.seal(msg)
            return all([bus.publish(b, channel, data) for b in buses])
        if self.silenced(agent):
            return False
        for fault in self._of(agent, "sensor"):
            msg = _sense(fault, topic, msg)
        inproc = node.context.inproc_bus
        local = [b for b in buses if b == inproc]
        network = [b for b in buses if b != inproc]
        if not network and node.settings.topic_buses(topic):
            # The topic's configured bus is the in-process one (a memq:// swarm bus): the agent's
            # own nodes and the network are one bus, so what the network loses they lose too.
            local, network = [], local
        ok = True
        if local:
            data = node.admission.seal(msg)
            ok = all([bus.publish(b, channel, data) for b in local])
        if not network:
            return ok
        for fault in self._of(agent, "packet_loss"):
            step = fault.step
            if topic in step.topics and step.direction != "in" and fault.rng.random() < step.loss:
                return ok
        delay = max(
            (
                f.step.delay
                for f in self._of(agent, "packet_loss")
                if topic in f.step.topics and f.step.direction != "in"
            ),
            default=0.0,
        )
        honest = msg
        for fault in self._of(agent, "byzantine"):
            msg = _lie(fault.step, topic, msg)
        if msg is not honest and not local:
            # The lie reaches the agent's own nodes on the shared bus: they take the truth back
            # (:meth:`receiving`), a liar knows what it is.
            header = honest.header
            self._truth[(agent, channel, int(header.seq), int(header.utime))] = honest
            if len(self._truth) > _REMEMBERED:
                del self._truth[next(iter(self._truth))]
        data = node.admission.seal(msg)
        for fault in self._of(agent, "packet_loss"):
            step = fault.step
            if topic in step.topics and step.direction != "in" and fault.over_cap("out", len(data), node.now):
                return ok
        if delay > 0.0:
            node.context.executor.call_later(delay, lambda: [bus.publish(b, channel, data) for b in network])
            return ok
        return all([bus.publish(b, channel, data) for b in network]) and ok

    # --------------------------------------------------------------------- receiving
    def receiving(self, node: Node, topic: str, handler: Callable[..., None]) -> Callable[..., None]:
        agent = node.agent
        if _watches(node):

            def operator_receives(msg: Any, *rest: Any) -> None:
                if not self.link_lost(str(msg.header.agent)):
                    handler(msg, *rest)

            return operator_receives
        reception = self.broadcast.get(agent) if topic in BROADCAST_TOPICS else None
        from_operator = topic in OPERATOR_INPUTS
        executor = node.context.executor

        truth = self._truth

        def agent_receives(msg: Any, *rest: Any) -> None:
            header = msg.header
            if truth and header.agent == agent:
                key = (
                    agent,
                    rest[0].channel if rest else node.channel(topic),
                    int(header.seq),
                    int(header.utime),
                )
                msg = truth.get(key, msg)
            active = bool(self.active.get(agent))
            if active and (self.silenced(agent) or (from_operator and self.link_lost(agent))):
                return  # a dead, frozen or cut-off agent is offered nothing: no broadcast draw either
            if reception is not None and not reception.admit(
                (topic, str(header.agent), int(header.seq), int(header.utime))
            ):
                return
            if not active:
                handler(msg, *rest)
                return
            delay = 0.0
            if header.agent != agent:  # from the network: another agent, the operator
                for fault in self._of(agent, "packet_loss"):
                    step = fault.step
                    if topic in step.topics and step.direction != "out":
                        if step.loss > 0.0 and fault.rng.random() < step.loss:
                            return
                        if fault.bucket is not None and fault.over_cap("in", len(msg.encode()), node.now):
                            return
                        delay = max(delay, step.delay)
            if delay > 0.0:
                executor.call_later(delay, lambda: None if self.silenced(agent) else handler(msg, *rest))
            else:
                handler(msg, *rest)

        return agent_receives


def lossy_broadcasts(nodes: list[Node], reception: float, seed: int) -> FaultGate:
    """A gate that loses broadcasts at the agents of ``nodes`` (each agent its own stream), set on
    every one of them; ``antalate agent --shard`` does this in each process of ``antalate run``."""
    names = sorted({n.agent for n in nodes})
    gate = FaultGate(broadcast={n: BroadcastReception(reception, seed, n) for n in names})
    for node in nodes:
        node.interference = gate
    return gate


def broadcast_report(gate: FaultGate) -> list[str]:
    """What each agent heard of the broadcasts, one line each."""
    lines = []
    for agent, r in sorted(gate.broadcast.items()):
        share = f"{r.heard / r.offered:.0%}" if r.offered else "-"
        lines.append(
            f"broadcast: {agent} heard {r.heard} of {r.offered} broadcast messages ({share}; p = {r.probability:g})"
        )
    return lines


def _copy(msg: Message) -> Any:
    return type(msg).decode(msg.encode())


def _moved(msg: telemetry_t, offset: tuple[float, float]) -> telemetry_t:
    out: telemetry_t = _copy(msg)
    out.lat, out.lon = geo_offset(float(msg.lat), float(msg.lon), offset[0], offset[1])
    return out


def _sense(fault: _Active, topic: str, msg: Message) -> Message:
    """What a faulty sensor reports instead of ``msg`` (the same message when it is another topic's)."""
    step = fault.step
    if step.sensor == "position" and isinstance(msg, telemetry_t):
        if step.mode == "bias":
            return _moved(msg, step.offset or (0.0, 0.0))
        if fault.stuck is None:
            fault.stuck = _copy(msg)
        stuck = fault.stuck
        assert isinstance(stuck, telemetry_t)
        out: telemetry_t = _copy(msg)
        out.lat, out.lon, out.alt = stuck.lat, stuck.lon, stuck.alt
        out.vn = out.ve = out.vd = 0.0
        return out
    if step.sensor == "peers" and isinstance(msg, peer_scan_t):
        if step.mode == "stuck":
            if fault.stuck is None:
                fault.stuck = _copy(msg)
            scan: peer_scan_t = _copy(fault.stuck)
            scan.header = msg.header
            return scan
        scan = _copy(msg)
        rb, bb = step.range_bias or 0.0, step.bearing_bias or 0.0
        scan.range = [max(0.0, float(r) + rb) for r in msg.range]
        scan.bearing = [wrap_180(float(b) + bb) for b in msg.bearing]
        return scan
    return msg


def _lie(step: FaultStep, topic: str, msg: Message) -> Message:
    """What a byzantine agent tells the others instead of ``msg``."""
    if step.offset is not None and isinstance(msg, telemetry_t):
        return _moved(msg, step.offset)
    if step.state is not None and isinstance(msg, mc_state_t):
        out: mc_state_t = _copy(msg)
        out.state = int(McState[step.state])
        return out
    return msg


def _watches(node: Node) -> bool:
    """Whether ``node`` watches the agents rather than flying one (the scripted operator, the console:
    built with ``watcher=True``): no agent's fault is its own, only an agent's link loss cuts what it
    hears of that agent. Its role as the node declared it (kept by its admission), never its kind's text."""
    return node.admission.watcher


def agents_gate(nodes: list[Node], script: Script) -> FaultGate:
    """The gate between these agents' nodes and the bus, set on every one of them: the script's
    broadcast losses when it has some, else a gate for its faults alone."""
    if script.broadcast.reception < 1.0:
        return lossy_broadcasts(nodes, script.broadcast.reception, script.seed)
    gate = FaultGate()
    for node in nodes:
        node.interference = gate
    return gate


__all__ = [
    "BROADCAST_TOPICS",
    "BroadcastReception",
    "FaultGate",
    "agents_gate",
    "broadcast_report",
    "lossy_broadcasts",
]
