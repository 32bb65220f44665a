"""Faults with the agents over several processes (``antalate run --processes P``).

Each agent process (``antalate agent --shard``) injects the script's faults into its own agents --
the gate sits between those agents' nodes and the network, the sim vehicles are there -- and
writes each fault's record on the recorded bus, where the operator's process records it. The
faults' times count from the whole swarm's MISSION as the scripted operator saw it: the operator's
process writes that moment as a record of its own (``kind = "mission"``, ``event = "start"``,
``agent = "operator"``), and each agent process starts its clock when it hears it. Back the other
way, the operator's process reads the agent processes' records to do its part: it waits no more
for an agent that crashed, and hears nothing from an agent whose link to it is lost.

The records are signed with the swarm key when there is one, and only signed ones are believed:
a forged "mission start" or "crash" on the LAN is dropped like any forged message.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any

from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import payload_t
from antalate_lcm.runtime.faults import FaultGate, FaultInjector, agents_gate
from antalate_lcm.runtime.script import Script
from antalate_lcm.wire.topics import FAULT_CHANNEL, FAULT_CONTENT_TYPE

log = logging.getLogger("antalate.faults")

#: The record of the moment the faults' times count from.
MISSION_KIND = "mission"


def read_record(node: Node, msg: payload_t, channel: str) -> dict[str, Any] | None:
    """A fault record heard on the bus, if it is one and (with a swarm key) validly signed."""
    auth = node.admission.authenticator
    if auth is not None and auth.check(msg, channel) is not None:
        return None
    if msg.content_type != FAULT_CONTENT_TYPE:
        return None
    try:
        record = json.loads(bytes(msg.data))
    except ValueError:
        return None
    return record if isinstance(record, dict) else None


class ShardFaults(FaultInjector):
    """The faults of one agent process's agents, timed from the operator's "mission start" record."""

    def __init__(self, settings: NodeSettings, context: Context, **kwargs: Any) -> None:
        super().__init__(settings, context, mission_start=lambda: self.mission_heard, **kwargs)
        #: When this process heard the operator's "mission start" (its clock), None before.
        self.mission_heard: float | None = None

    def on_start(self) -> None:
        super().on_start()
        self.context.buses.subscribe(self._bus, FAULT_CHANNEL, payload_t, self._heard)

    def _heard(self, channel: str, msg: payload_t) -> None:
        record = read_record(self, msg, channel)
        if record is None or self.mission_heard is not None:
            return
        if record.get("kind") == MISSION_KIND and record.get("event") == "start":
            self.mission_heard = self.now
            log.info("%s: the mission started: the script's faults count from now", self.agent)


def shard_faults(
    configs: list[Config],
    context: Context,
    nodes: list[Node],
    script: Script,
    *,
    bus: str,
    name: str,
) -> ShardFaults:
    """The fault injector of this process's agents, its gate set on their nodes (broadcast losses too)."""
    from antalate_lcm.agent.hlc.node import HlcNode

    return ShardFaults(
        NodeSettings.from_config(configs[0], agent=name),
        context,
        script=script,
        agents=[c.agent.name for c in configs],
        gate=agents_gate(nodes, script),
        bus=bus,
        excuse=lambda _agent: None,
        vehicles={n.agent: n.adapter for n in nodes if isinstance(n, HlcNode)},
    )


class FaultRelay(FaultInjector):
    """The operator's process's side: it writes the mission's start, and acts on the records of the
    agent processes (an agent that crashed is excused, a lost link cuts the operator's side too).

    It plans no fault of its own: the agents are elsewhere."""

    def __init__(
        self,
        settings: NodeSettings,
        context: Context,
        *,
        script: Script,
        gate: FaultGate,
        bus: str,
        excuse: Callable[[str], None],
    ) -> None:
        super().__init__(
            settings,
            context,
            script=script,
            agents=[],
            gate=gate,
            bus=bus,
            mission_start=lambda: None,
            excuse=excuse,
            vehicles={},
        )
        self._script = script
        self._marked = False

    def on_start(self) -> None:
        super().on_start()
        self.context.buses.subscribe(self._bus, FAULT_CHANNEL, payload_t, self._heard)

    def _step(self) -> None:
        if self._script.fault and not self._marked and self.mission_start() is not None:
            self._marked = True
            self._publish_record({"agent": "operator", "kind": MISSION_KIND, "event": "start", "at": 0.0})

    def _heard(self, channel: str, msg: payload_t) -> None:
        record = read_record(self, msg, channel)
        if record is None or record.get("kind") in (MISSION_KIND, "broadcast"):
            return
        agent, kind, event = str(record.get("agent")), str(record.get("kind")), str(record.get("event"))
        index = record.get("fault")
        if not isinstance(index, int) or not 0 <= index < len(self._script.fault):
            return
        step = self._script.fault[index]
        if step.kind != kind:
            return
        at = record.get("at")
        since = float(at) if isinstance(at, int | float) else 0.0
        label = " ".join(x for x in (step.kind, step.sensor, step.vehicle) if x)
        self.events.append((since, agent, label, event, step.since))
        if event == "start":
            if kind == "crash" or (kind in ("freeze", "link_loss") and step.duration == 0.0):
                self.excuse(agent)
            if kind == "link_loss":
                self.gate.activate(step, index, agent, self._script.seed)
        elif event == "end" and kind == "link_loss":
            self.gate.deactivate(step, index, agent)

    def summarize(self) -> None:
        """The agent processes print what their agents heard of the broadcasts (stderr)."""
