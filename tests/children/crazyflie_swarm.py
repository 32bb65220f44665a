"""Crazyflie agents against their emulators in one process, reporting what happens as JSON lines
(tests/vehicles/test_crazyflie_e2e.py's ``Driver`` is the other end).

The spec (argv[1], JSON) lists the agents (``doc``: the agent's config, ``emu``: the emulator's
settings) and optionally a scripted ``operator``. Events on stdout: ``started``, ``mc``/``hlc`` state
changes, ``error``, ``emu`` snapshots every 0.1 s, ``silent``, ``operator`` (its report) and ``stopped``.
Commands on stdin: ``silent I 0|1``, ``battery I PCT``, ``direction AZIMUTH SPEED``, ``stop``.

    python -m tests.children.crazyflie_swarm SPEC
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from typing import Any

from antalate_lcm.agent.hlc.machine import ErrorCode
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import direction_cmd_t
from antalate_lcm.runtime.agent import agent_nodes, shared_buses, validate
from antalate_lcm.runtime.scripted_operator import ScriptedOperator
from antalate_lcm.wire.vocabulary import HlcState, McState
from tests.children.events import emit
from tests.emulators.crazyflie_emulator import CrazyflieEmulator


class Recorder(Node):
    """Reports every agent's state changes and errors, the emulators' truth, and steers the swarm."""

    kind = "recorder"

    def __init__(
        self, settings: NodeSettings, context: Context, names: list[str], emus: list[CrazyflieEmulator]
    ) -> None:
        super().__init__(settings, context)
        self.names = names
        self.emus = emus
        self.last: dict[tuple[str, str], str] = {}
        self.direction: tuple[float, float, float] | None = None

    def on_start(self) -> None:
        self.subscribe_all("MC_STATE", self.on_mc)
        self.subscribe_all("HLC_STATE", self.on_hlc)
        self.subscribe_all("HLC_ERROR", self.on_error)
        self.create_timer(0.1, self.tick)

    def on_mc(self, m: Any, match: TopicMatch) -> None:
        self.state("mc", m.header.agent, McState(m.state).name)

    def on_hlc(self, m: Any, match: TopicMatch) -> None:
        self.state("hlc", m.header.agent, HlcState(m.state).name)

    def on_error(self, m: Any, match: TopicMatch) -> None:
        emit(kind="error", agent=m.header.agent, code=ErrorCode(m.code).name, text=m.text)

    def state(self, kind: str, agent: str, name: str) -> None:
        if self.last.get((kind, agent)) != name:
            self.last[(kind, agent)] = name
            emit(kind=kind, agent=agent, state=name)

    def tick(self) -> None:
        for name, emu in zip(self.names, self.emus, strict=True):
            s = emu.snapshot()
            emit(
                kind="emu",
                agent=name,
                x=s.x,
                y=s.y,
                z=s.z,
                vx=s.vx,
                vy=s.vy,
                vz=s.vz,
                armed=s.armed,
                flying=s.flying,
                vbat=s.vbat,
            )
        if self.direction is not None and self.now - self.direction[2] >= 0.5:
            self.send_direction(*self.direction[:2])

    def send_direction(self, azimuth: float, speed: float) -> None:
        msg = direction_cmd_t()
        msg.active, msg.azimuth, msg.speed, msg.target = speed > 0, azimuth, speed, ""
        self.publish("SWARM_DIRECTION_CMD", msg)
        self.direction = (azimuth, speed, self.now) if speed > 0 else None


def watch_operator(operator: ScriptedOperator) -> None:
    while not operator.finished:
        time.sleep(0.1)
    emit(kind="operator", phase=operator.phase.name, report=operator.report())


def main(spec: dict[str, Any]) -> None:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(name)s %(message)s")
    emus: list[CrazyflieEmulator] = []
    configs: list[Config] = []
    for item in spec["agents"]:
        emu = CrazyflieEmulator(**item["emu"]).start()
        emus.append(emu)
        doc = item["doc"]
        doc["hlc"]["autopilot_params"]["uri"] = emu.uri
        config = parse_config(doc, "<test>")
        validate(config)
        configs.append(config)
    names = [c.agent.name for c in configs]

    context = Context.in_process(shared_buses(configs))
    recorder = Recorder(NodeSettings.from_config(configs[0], agent="recorder"), context, names, emus)
    nodes: list[Node] = [recorder] + [n for c in configs for n in agent_nodes(c, context)]
    operator = None
    if spec.get("operator"):
        operator = ScriptedOperator(
            NodeSettings.from_config(configs[0], agent="operator"),
            context,
            expected_agents=len(configs),
            mission_time=spec["operator"]["mission_time"],
            timeout=120.0,
        )
        nodes.append(operator)
    context.buses.open()
    context.executor.start()
    for node in nodes:
        node.start()
    emit(kind="started")

    if operator is not None:
        threading.Thread(target=watch_operator, args=(operator,), daemon=True).start()
    for line in sys.stdin:
        words = line.split()
        if words == ["stop"]:
            break
        if words[:1] == ["silent"]:
            emus[int(words[1])].set_silent(words[2] == "1")
            emit(kind="silent", agent=names[int(words[1])], on=words[2] == "1")
        elif words[:1] == ["battery"]:
            emus[int(words[1])].set_battery(float(words[2]))
        elif words[:1] == ["direction"]:
            context.executor.call_soon(recorder.send_direction, float(words[1]), float(words[2]))
    for node in reversed(nodes):
        node.stop()
    context.close()
    for emu in emus:
        emu.stop()
    emit(kind="stopped")


if __name__ == "__main__":
    main(json.loads(sys.argv[1]))
