"""Faults an experiment's script injects into simulated agents, and lossy broadcast control.

The paper's lab studies swarms under imperfect conditions: agents that die, freeze, lie or sense
wrongly, and broadcast control signals "acquired by only a random set of the swarm's agents"
(Segall & Bruckstein). ``antalate run`` models them where they happen on a real agent -- between
the agent's software and the network -- through the one hook every node has
(:class:`antalate_lcm.core.node.Interference`): what a node sends, what it consumes, and whether its
timers run. The behaviors, MC, HLC and configs are the ones that fly; nothing is mocked.

* crash: the agent's software is dead from ``at`` on: no timer runs, nothing is sent or consumed
  (the vehicle is left where the software left it, as a vehicle whose companion computer died).
* freeze: the same for ``duration`` s, then the agent carries on (a hung process, a GC pause).
* sensor: the position in the agent's telemetry (what its own behaviors and every peer see of it)
  stuck at its value at ``at``, or biased by ``offset`` m; or its peer sensor's scans
  (``peer_scan_t``) stuck or biased by ``range_bias`` m and ``bearing_bias`` deg.
* byzantine: the agent sends false telemetry positions (``offset``) or a false MC state
  (``state``) to the network, signed with the swarm key it holds, while its own nodes (in memory)
  keep the truth: a liar, not a broken sensor.
* battery: the sim vehicle's battery drops to ``level`` percent, and/or drains ``drain`` %/min
  more (the sim's own failsafes then act: a battery warning, LAND when empty).
* link_loss: the operator hears nothing from the agent and the agent nothing from the operator.
* vehicle: the sim vehicle's own faults (antalate_lcm/autopilot/sim.py): its failsafe (``rtl``,
  ``land`` or ``brake``), a pilot takeover, a lost link between the HLC and the vehicle, or an
  adapter whose ``state()`` raises, for ``duration`` s (the last two).
* packet_loss: the agent's messages on ``topics`` are lost with probability ``loss`` and/or
  delayed ``delay`` s, sent (``out``), received from the network (``in``) or both; with
  ``bandwidth`` the topics together carry at most that many bytes a second each way (a token
  bucket of ``burst`` bytes, a policer: a message the bucket cannot pay for is lost).

Each fault is drawn per agent with its ``probability`` from the script's ``seed`` (so a run with
the same script hits the same agents), and each start, end and spared draw is written to the
recorded bus on :data:`FAULT_CHANNEL` (a ``payload_t`` holding JSON), where ``antalate analyze``
lists it. Broadcast reception (:class:`BroadcastReception`) is decided at each receiving agent,
independently per agent and per message, from a seeded stream of its own.
"""

from __future__ import annotations

import json
import logging
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from antalate_lcm.base.geo import offset as geo_offset
from antalate_lcm.base.geo import wrap_180
from antalate_lcm.base.ratelimit import TokenBucket
from antalate_lcm.core.node import Context, Node
from antalate_lcm.msgs import mc_state_t, payload_t, peer_scan_t, telemetry_t
from antalate_lcm.runtime.script import VEHICLE_EVENTS, FaultStep, Script
from antalate_lcm.wire.topics import FAULT_CHANNEL, FAULT_CONTENT_TYPE, OPERATOR_INPUTS, Message
from antalate_lcm.wire.vocabulary import McState

log = logging.getLogger("antalate.faults")

#: The broadcast control topics (one message reaches every agent) whose reception is lossy.
BROADCAST_TOPICS = frozenset({"SWARM_OPERATOR_CMD", "SWARM_DIRECTION_CMD"})
#: Broadcast decisions an agent remembers, so its nodes that consume one message agree on it.
_REMEMBERED = 256
#: s between two looks at the schedule: the precision of a fault's time.
_STEP = 0.05


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
class _Planned:
    index: int
    step: FaultStep
    agent: str
    hit: bool
    #: When it comes (s since its ``since``): the step's ``at``, or drawn up to its ``at_latest``.
    at: float = 0.0
    started: bool = False
    ended: bool = False


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
        bus = node.context.bus
        if node.kind == "operator" or not self.active.get(agent):
            data = node.seal(msg)
            return all([bus.publish(b, channel, data) for b in buses])
        if self.silenced(agent):
            return False
        for fault in self._of(agent, "sensor"):
            msg = _sense(fault, topic, msg)
        inproc = node.context.inproc_bus
        local = [b for b in buses if b == inproc]
        network = [b for b in buses if b != inproc]
        if not network and node.config.topic_buses(topic):
            # The topic's configured bus is the in-process one (a memq:// swarm bus): the agent's
            # own nodes and the network are one bus, so what the network loses they lose too.
            local, network = [], local
        ok = True
        if local:
            data = node.seal(msg)
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
        data = node.seal(msg)
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
        if node.kind == "operator":

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


def plan(script: Script, agents: list[str]) -> list[_Planned]:
    """Who each fault hits: every agent it names, each with the fault's probability, drawn from a
    stream of its own seeded by (seed, fault, agent) so adding a fault changes no other draw."""
    out = []
    for i, step in enumerate(script.fault):
        for agent in step.agents(agents):
            hit = random.Random(f"fault/{script.seed}/{i}/{agent}").random() < step.probability
            at = step.at
            if step.at_latest is not None:  # a stream of its own: the hits stay those of a fixed time
                at = random.Random(f"fault-at/{script.seed}/{i}/{agent}").uniform(step.at, step.at_latest)
            out.append(_Planned(i, step, agent, hit, at))
    return out


class FaultInjector(Node):
    """Starts and ends the script's faults at their times (s after the whole swarm entered
    MISSION), and writes each to the recorded bus."""

    kind = "faults"

    def __init__(
        self,
        config: Any,
        context: Context,
        *,
        script: Script,
        agents: list[str],
        gate: FaultGate,
        bus: str,
        mission_start: Callable[[], float | None],
        excuse: Callable[[str], None],
        vehicles: Mapping[str, Any],
    ) -> None:
        super().__init__(config, context, name="faults")
        self.gate = gate
        self.planned = plan(script, agents)
        self.seed = script.seed
        self._bus = bus
        #: When the whole swarm entered MISSION (the operator's), None before.
        self.mission_start = mission_start
        #: Tells the operator to wait no more for an agent.
        self.excuse = excuse
        self._vehicles = vehicles
        self._drains: dict[str, float] = {}
        self._last_drain = 0.0
        self._seq = 0
        #: When this node started (the clock of the faults with since = "start").
        self.run_start = 0.0
        #: What happened, in order: (s since its origin, agent, kind, event, origin: mission or start).
        self.events: list[tuple[float, str, str, str, str]] = []

    def on_start(self) -> None:
        self.run_start = self.now
        self.create_timer(_STEP, self._step)

    def _step(self) -> None:
        mission = self.mission_start()
        for p in self.planned:
            if p.ended:
                continue
            start = self.run_start if p.step.since == "start" else mission
            if start is None:
                continue
            since = self.now - start
            if not p.started and since >= p.at:
                p.started = True
                if not p.hit:
                    p.ended = True
                    self._record(since, p, "spared")
                    continue
                self._begin(since, p)
            elif p.started and p.step.duration > 0.0 and since >= p.at + p.step.duration:
                self._end(since, p)
        self._drain()

    def _begin(self, since: float, p: _Planned) -> None:
        step = p.step
        if step.kind == "vehicle":
            self._vehicle(p, start=True)
        elif step.kind == "battery":
            p.ended = True  # happens once; a drain goes on to the end
            vehicle = self._vehicles[p.agent]
            if step.level is not None:
                vehicle.set_battery(min(float(vehicle.battery), step.level))
            if step.drain is not None:
                self._drain()  # the other drains up to now, at their rates
                self._drains[p.agent] = self._drains.get(p.agent, 0.0) + step.drain
                self._last_drain = self.now
        else:
            self.gate.activate(step, p.index, p.agent, self.seed)
            if step.kind == "crash" or (step.kind in ("freeze", "link_loss") and step.duration == 0.0):
                self.excuse(p.agent)  # the operator waits no more for an agent it can never hear again
        self._record(since, p, "start")

    def _vehicle(self, p: _Planned, *, start: bool) -> None:
        """The sim's own fault injection, on the executor thread as every call of the HLC."""
        vehicle, what = self._vehicles[p.agent], p.step.vehicle
        if what == "failsafe":
            vehicle.trigger_failsafe(p.step.failsafe, "failsafe injected by the experiment's script")
        elif what == "pilot_takeover":
            vehicle.pilot_takeover()
        elif what == "link_loss":
            vehicle.set_link_loss(start)
        elif what == "state_error":
            vehicle.set_state_error(
                "fault injected by the experiment's script: state() failed" if start else None
            )
        if what in VEHICLE_EVENTS:
            p.ended = True

    def _end(self, since: float, p: _Planned) -> None:
        p.ended = True
        if p.step.kind == "vehicle":
            self._vehicle(p, start=False)
            self._record(since, p, "end")
            return
        self.gate.deactivate(p.step, p.index, p.agent)
        self._record(since, p, "end")

    def _drain(self) -> None:
        if not self._drains:
            return
        now = self.now
        dt, self._last_drain = now - self._last_drain, now
        for agent, rate in self._drains.items():
            vehicle = self._vehicles[agent]
            if vehicle.in_air:
                vehicle.set_battery(max(0.0, float(vehicle.battery) - rate * dt / 60.0))

    def _record(self, since: float, p: _Planned, event: str) -> None:
        step = p.step
        detail = step.model_dump(exclude_defaults=True, exclude={"kind", "agent", "at"})
        label = " ".join(x for x in (step.kind, step.sensor, step.vehicle) if x)
        self.events.append((since, p.agent, label, event, step.since))
        log.info(
            "fault %s %s of %s at %.2f s of the mission %s", step.kind, event, p.agent, since, detail or ""
        )
        self._publish_record(
            {
                "agent": p.agent,
                "kind": step.kind,
                "event": event,
                "at": round(since, 3),
                "fault": p.index,
                **detail,
            }
        )

    def _publish_record(self, record: dict[str, Any]) -> None:
        msg = payload_t()
        msg.content_type = FAULT_CONTENT_TYPE
        data = json.dumps(record, sort_keys=True).encode()
        msg.size, msg.data = len(data), data
        self._seq += 1
        msg.header.utime = int(self.wallclock() * 1_000_000)
        msg.header.agent = self.agent  # one sender per process: each has its own seq
        msg.header.seq = self._seq
        self.context.bus.publish(self._bus, FAULT_CHANNEL, self.seal(msg))

    def summarize(self) -> None:
        """Write what each agent heard of the broadcasts (at the end of the script: once the nodes
        stop, nothing published reaches the recorder any more)."""
        for agent, reception in sorted(self.gate.broadcast.items()):
            self._publish_record(
                {
                    "agent": agent,
                    "kind": "broadcast",
                    "event": "summary",
                    "reception": reception.probability,
                    "offered": reception.offered,
                    "heard": reception.heard,
                }
            )

    def report(self) -> list[str]:
        """Lines for the run's report: each fault that happened, and what each agent heard."""
        lines = [
            f"fault: {kind} {event} {agent} at {t:.1f} s of the {'mission' if origin == 'mission' else 'run'}"
            for t, agent, kind, event, origin in self.events
        ]
        return lines + broadcast_report(self.gate)
