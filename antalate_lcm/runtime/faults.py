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
* vehicle: the sim vehicle's own faults (antalate_lcm/vehicles/sim/faults.py): its failsafe (``rtl``,
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
from dataclasses import dataclass
from typing import Any

from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import payload_t
from antalate_lcm.runtime.fault_gate import (
    BROADCAST_TOPICS,
    BroadcastReception,
    FaultGate,
    agents_gate,
    broadcast_report,
    lossy_broadcasts,
)
from antalate_lcm.runtime.script import VEHICLE_EVENTS, FaultStep, Script
from antalate_lcm.wire.topics import FAULT_CHANNEL, FAULT_CONTENT_TYPE

log = logging.getLogger("antalate.faults")

#: s between two looks at the schedule: the precision of a fault's time.
_STEP = 0.05


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
        settings: NodeSettings,
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
        super().__init__(settings, context, name="faults")
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
        self.context.buses.publish(self._bus, FAULT_CHANNEL, self.admission.seal(msg))

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


__all__ = [
    "BROADCAST_TOPICS",
    "BroadcastReception",
    "FaultGate",
    "FaultInjector",
    "agents_gate",
    "broadcast_report",
    "lossy_broadcasts",
    "plan",
]
