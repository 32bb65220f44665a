"""The console's LCM side: a :class:`~antalate_lcm.node.Node` that watches every agent.

Receiving (measured with 200 agents × 3 topics × 5 Hz, benchmarks/tui.py): the usual node path —
decode on the bus thread, hop to the executor thread, then hand to the UI — cost about 15 % of a
core in thread hand-offs alone. The console has no node logic to run on the executor, so it
subscribes to raw datagrams and the bus thread only appends ``(channel, bytes, time)`` to a
deque (atomic, no lock); the UI thread drains it on its refresh timer, a few batches per second
instead of thousands of cross-thread calls, and decodes there. A telemetry sample superseded by a
newer one from the same agent within one batch is never shown, so it is not even decoded. State
messages are all decoded: each ``mc_state_t`` may carry an acknowledgement, each HLC change an event.

Sending happens on the caller's (UI) thread, and only there, through :meth:`Node.publish` (which
stamps the header, signs with the swarm key and hands the datagram to the thread-safe bus), so a
key press reaches the wire without waiting for either thread. The console owns the ``header.seq``
of operator commands (a resend must repeat it, see :mod:`operator_tui.commands`) and passes it to
``publish``; ``utime`` is fresh on every send, so a resend passes the agents' replay guard.
"""

from __future__ import annotations

import logging
import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from antalate_lcm._ratelimit import RateLimitedLog
from antalate_lcm.bus import Subscription
from antalate_lcm.config import Config
from antalate_lcm.msgs import direction_cmd_t, operator_cmd_t
from antalate_lcm.node import Context, Node
from antalate_lcm.topics import channel_regex
from operator_tui.commands import COMMANDS
from operator_tui.model import WATCHED_TOPICS

log = logging.getLogger("antalate.operator")

#: Topics where only the latest message per channel matters (samples, not events).
COALESCED = frozenset({"TELEMETRY"})


def _any_fields(template: str) -> str:
    """A group-free regex for every channel a template can produce (for one combined pattern)."""
    return re.sub(r"\\\{\w+\\\}", "[^/]+", re.escape(template))


@dataclass(frozen=True, slots=True)
class Incoming:
    """A decoded message for the UI: which topic, which agent (from the channel), when it arrived."""

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
        self.inbox: deque[tuple[str, bytes, float]] = deque()
        self.swarm_key = config.security.swarm_key
        self._direction_seq = 0
        self._raw_subs: list[Subscription] = []
        self._decoders: dict[str, tuple[type, re.Pattern[str]]] = {}
        self._channels: dict[str, tuple[str, dict[str, str]] | None] = {}
        self._decode_log = RateLimitedLog(log)
        self.sent = 0
        self.received = 0
        self.skipped = 0
        self.decode_errors = 0

    def on_start(self) -> None:
        by_bus: dict[str, list[str]] = {}
        for topic in WATCHED_TOPICS:
            spec = self.topic_spec(topic)
            self._decoders[topic] = (spec.msg_type, re.compile(channel_regex(spec.channel)))
            by_bus.setdefault(self.config.topic_buses(topic)[0], []).append(topic)
        for bus, topics in by_bus.items():
            # One regex per bus, not one per topic: the bus matches every datagram against every
            # pattern subscription; which topic a channel is gets worked out once per channel.
            combined = "|".join(f"(?:{_any_fields(self.topic_spec(t).channel)})" for t in topics)
            self._raw_subs.append(self.context.bus.subscribe(bus, combined, None, self._enqueue, regex=True))

    def on_stop(self) -> None:
        for sub in self._raw_subs:
            self.context.bus.unsubscribe(sub)
        self._raw_subs.clear()

    def _enqueue(self, channel: str, data: bytes) -> None:
        """On the bus thread: timestamp and queue, nothing else."""
        self.inbox.append((channel, data, self.clock()))

    def _classify(self, channel: str) -> tuple[str, dict[str, str]] | None:
        """(topic, template fields) of a channel, remembered: there are only agents × topics of them."""
        try:
            return self._channels[channel]
        except KeyError:
            pass
        found: tuple[str, dict[str, str]] | None = None
        for topic, (_, pattern) in self._decoders.items():
            m = pattern.fullmatch(channel)
            if m is not None:
                found = (topic, m.groupdict())
                break
        self._channels[channel] = found
        return found

    def drain(self) -> list[Incoming]:
        """Decode everything received since the last call (on the UI thread)."""
        raw: list[tuple[str, bytes, float]] = []
        pop = self.inbox.popleft
        try:
            while True:
                raw.append(pop())
        except IndexError:
            pass
        self.received += len(raw)
        classify = self._classify
        latest: dict[str, int] = {}
        for i, (channel, _, _) in enumerate(raw):
            kind = classify(channel)
            if kind is not None and kind[0] in COALESCED:
                latest[channel] = i
        out: list[Incoming] = []
        for i, (channel, data, received) in enumerate(raw):
            kind = classify(channel)
            if kind is None:
                continue
            topic, fields = kind
            if topic in COALESCED and latest[channel] != i:
                self.skipped += 1
                continue
            msg_type = self._decoders[topic][0]
            try:
                msg = msg_type.decode(data)
            except Exception as exc:  # noqa: BLE001 - garbage on the bus must not take the console down
                self.decode_errors += 1
                self._decode_log.log(
                    channel,
                    logging.WARNING,
                    "dropped a %d-byte datagram on %s that is not a valid %s (%s)",
                    len(data),
                    channel,
                    msg_type.__name__,
                    exc,
                )
                continue
            out.append(Incoming(topic, fields.get("agent") or msg.header.agent, msg, received, fields))
        return out

    # ------------------------------------------------------------------ sending (the UI thread)
    def _send(self, topic: str, msg: Any, target: str, seq: int) -> str:
        fields = {"agent": target} if target else {}
        self.publish(topic, msg, seq=seq, **fields)
        self.sent += 1
        return self.channel(topic, **fields)

    def send_operator_cmd(self, command: str, target: str, seq: int, *, altitude: float = 0.0) -> str:
        """Send (or resend: same seq, fresh utime and MAC) an operator command; returns the channel.

        ``target`` "" goes to every agent on SWARM_OPERATOR_CMD, otherwise on the agent's OPERATOR_CMD.
        """
        msg = operator_cmd_t()
        msg.command = COMMANDS[command]
        msg.target = target
        msg.altitude = altitude
        return self._send("OPERATOR_CMD" if target else "SWARM_OPERATOR_CMD", msg, target, seq)

    def send_direction(self, *, active: bool, azimuth: float, speed: float, target: str) -> str:
        """Send a direction command to one agent, or to every agent when ``target`` is ""."""
        self._direction_seq += 1
        msg = direction_cmd_t()
        msg.active = active
        msg.azimuth = azimuth
        msg.speed = speed
        msg.target = target
        return self._send("DIRECTION_CMD" if target else "SWARM_DIRECTION_CMD", msg, target, self._direction_seq)

    def bus_summary(self) -> str:
        """'lan=udpm://…' for the topics the console watches (shown in the status bar)."""
        names = sorted({b for t in WATCHED_TOPICS for b in self.config.topic_buses(t)[:1]})
        return ", ".join(f"{n}={self.config.buses[n]}" for n in names)
