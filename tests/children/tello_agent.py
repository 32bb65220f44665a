"""One Tello agent in a process of its own, reporting what happens as JSON lines
(tests/vehicles/test_tello_e2e.py's ``Agent`` is the other end).

The agent's config is argv[1] (JSON). Events on stdout: ``started``, ``mc``/``hlc`` state changes,
``error``, ``telemetry`` (at most once a second) and ``stopped``. Commands on stdin:
``direction AZIMUTH SPEED`` (what the console's direction keys send) and ``stop``.

    python -m tests.children.tello_agent CONFIG
"""

from __future__ import annotations

import json
import logging
import sys
from typing import Any

from antalate_lcm.agent.hlc.machine import ErrorCode
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import direction_cmd_t
from antalate_lcm.runtime.agent import agent_nodes, validate
from antalate_lcm.wire.vocabulary import HlcState, McState
from tests.children.events import emit


class Recorder(Node):
    """Reports the agent's state changes, errors and (once a second) telemetry."""

    kind = "recorder"

    def __init__(self, config: Config, context: Context) -> None:
        super().__init__(NodeSettings.from_config(config), context)
        self.last: dict[str, str] = {}
        self.telemetry_at = 0.0

    def on_start(self) -> None:
        self.subscribe("MC_STATE", self.on_mc)
        self.subscribe("HLC_STATE", self.on_hlc)
        self.subscribe("HLC_ERROR", self.on_error)
        self.subscribe("TELEMETRY", self.telemetry)

    def on_mc(self, m: Any) -> None:
        self.state("mc", McState(m.state).name)

    def on_hlc(self, m: Any) -> None:
        self.state("hlc", HlcState(m.state).name)

    def on_error(self, m: Any) -> None:
        emit(kind="error", code=ErrorCode(m.code).name, text=m.text)

    def state(self, kind: str, name: str) -> None:
        if self.last.get(kind) != name:
            self.last[kind] = name
            emit(kind=kind, state=name)

    def telemetry(self, m: Any) -> None:
        if self.now - self.telemetry_at >= 1.0:
            self.telemetry_at = self.now
            emit(
                kind="telemetry",
                lat=m.lat,
                lon=m.lon,
                alt=m.alt,
                heading=m.heading,
                battery=m.battery,
                mode=m.mode,
                in_air=m.in_air,
            )


def main(doc: dict[str, Any]) -> None:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(name)s %(message)s")
    config = parse_config(doc, "<test>")
    validate(config)
    context = Context.create(config)
    nodes: list[Node] = [Recorder(config, context), *agent_nodes(config, context)]  # first: it hears INIT
    context.buses.open()
    context.executor.start()
    for node in nodes:
        node.start()
    emit(kind="started")
    for line in sys.stdin:
        words = line.split()
        if words == ["stop"]:
            break
        if words[:1] == ["direction"]:  # direction AZIMUTH SPEED: what the console's direction keys send
            msg = direction_cmd_t()
            msg.active, msg.azimuth, msg.speed, msg.target = (
                float(words[2]) > 0,
                float(words[1]),
                float(words[2]),
                "",
            )
            context.executor.call_soon(nodes[0].publish, "DIRECTION_CMD", msg)
    for node in reversed(nodes):
        node.stop()
    context.close()
    emit(kind="stopped")


if __name__ == "__main__":
    main(json.loads(sys.argv[1]))
