"""The console's LCM side: an ordinary :class:`~antalate_lcm.node.Node` that watches every agent.

Threading: the bus's dispatcher thread decodes, the executor thread runs :meth:`OperatorNode._enqueue`
(one ``deque.append``), and the UI thread drains the deque on a timer. So 200 agents × 20 msg/s
reach the UI as a handful of batches per second instead of thousands of cross-thread calls, and
the UI never waits on the network. ``deque.append``/``popleft`` are atomic, so no lock is needed.

Sending happens on the caller's (UI) thread straight to :meth:`Bus.publish` (thread-safe), so a
key press reaches the wire without waiting for either thread. The console owns the ``header.seq``
of operator commands (a resend must repeat it, see :mod:`operator_tui.commands`), so it does not
use :meth:`Node.publish`, which stamps a fresh seq on every message; it builds the header itself
and signs the final message when a swarm key is configured (DESIGN §10).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

from antalate_lcm.config import Config
from antalate_lcm.msgs import direction_cmd_t, operator_cmd_t
from antalate_lcm.node import Context, Node, TopicMatch
from antalate_lcm.security import sign
from operator_tui.commands import COMMANDS
from operator_tui.model import WATCHED_TOPICS


@dataclass(frozen=True, slots=True)
class Incoming:
    """A decoded message waiting for the UI: which topic, which agent (from the channel), when."""

    topic: str
    agent: str
    msg: Any
    received: float
    fields: dict[str, str]


class OperatorNode(Node):
    """Watches MC_STATE, HLC_STATE, TELEMETRY, HLC_ERROR and ARBITER of every agent; sends commands."""

    kind = "operator"

    def __init__(
        self,
        config: Config,
        context: Context,
        *,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(config, context)
        self.clock = clock
        self.wallclock = wallclock
        self.inbox: deque[Incoming] = deque()
        self.swarm_key = config.security.swarm_key
        self._direction_seq = 0
        self.sent = 0

    def on_start(self) -> None:
        for topic in WATCHED_TOPICS:
            self.subscribe_all(topic, partial(self._enqueue, topic))

    def _enqueue(self, topic: str, msg: Any, match: TopicMatch) -> None:
        agent = match.fields.get("agent") or msg.header.agent
        self.inbox.append(Incoming(topic, agent, msg, self.clock(), match.fields))

    def drain(self) -> list[Incoming]:
        """Everything received since the last call (called on the UI thread)."""
        out: list[Incoming] = []
        pop = self.inbox.popleft
        try:
            while True:
                out.append(pop())
        except IndexError:
            return out

    # ------------------------------------------------------------------ sending (any thread)
    def _header(self, msg: Any, seq: int) -> None:
        msg.header.utime = int(self.wallclock() * 1_000_000)
        msg.header.agent = self.agent
        msg.header.seq = seq

    def _send(self, topic: str, msg: Any, target: str) -> str:
        if self.swarm_key:
            sign(msg, self.swarm_key)
        data = msg.encode()
        channel = self.channel(topic, agent=target) if target else self.channel(topic)
        for bus in self.config.topic_buses(topic):
            self.context.bus.publish(bus, channel, data)
        self.sent += 1
        return channel

    def send_operator_cmd(self, command: str, target: str, seq: int, *, altitude: float = 0.0) -> str:
        """Send (or resend: same seq, fresh utime and MAC) an operator command; returns the channel.

        ``target`` "" goes to every agent on SWARM_OPERATOR_CMD, otherwise on the agent's OPERATOR_CMD.
        """
        msg = operator_cmd_t()
        self._header(msg, seq)
        msg.command = COMMANDS[command]
        msg.target = target
        msg.altitude = altitude
        return self._send("OPERATOR_CMD" if target else "SWARM_OPERATOR_CMD", msg, target)

    def send_direction(self, *, active: bool, azimuth: float, speed: float, target: str) -> str:
        """Send a direction command to one agent, or to every agent when ``target`` is ""."""
        self._direction_seq += 1
        msg = direction_cmd_t()
        self._header(msg, self._direction_seq)
        msg.active = active
        msg.azimuth = azimuth
        msg.speed = speed
        msg.target = target
        return self._send("DIRECTION_CMD" if target else "SWARM_DIRECTION_CMD", msg, target)

    def bus_summary(self) -> str:
        """'lan=udpm://…' for the topics the console watches (shown in the status bar)."""
        names = sorted({b for t in WATCHED_TOPICS for b in self.config.topic_buses(t)[:1]})
        return ", ".join(f"{n}={self.config.buses[n]}" for n in names)
