"""The console's LCM side: a :class:`~antalate_lcm.core.node.Node` that watches every agent.

Receiving (measured with 1,000 agents × 3 topics × 5 Hz, benchmarks/tui.py): the console has no
node logic to run on the executor, so it subscribes to raw datagrams, and the executor's loop only
files each one under its channel: the newest ``(bytes, time)`` per channel replaces the one before
(a dict store, atomic, no lock), events (HLC_ERROR) are appended to a deque. The UI thread takes
both on its refresh timer and decodes there, so it decodes at most one message per agent and
topic per tick whatever the rates, and nothing that a newer message superseded. The newest
``mc_state_t`` carries the newest acknowledgement (``last_command_seq`` only grows), so coalescing
states loses no acknowledgement; a state held for less than one tick is not shown.

Sending happens on the caller's (UI) thread, and only there, through :meth:`Node.publish` (which
stamps the header, has the node's admission sign it with the swarm key and hands the datagram to the thread-safe bus), so a
key press reaches the wire without waiting for either thread. The console owns the ``header.seq``
of operator commands (a resend must repeat it, see :mod:`operator_tui.commands`) and passes it to
``publish``; ``utime`` is fresh on every send, so a resend passes the agents' replay guard.
"""

from __future__ import annotations

import logging
import re
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.bus import Subscription
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import direction_cmd_t, operator_cmd_t
from antalate_lcm.wire.topics import Message, channel_regex
from operator_tui.board import WATCHED_TOPICS
from operator_tui.commands import COMMANDS

log = logging.getLogger("antalate.operator")

#: Topics where every message counts (events): the others keep only the newest per channel.
EVENTS = frozenset({"HLC_ERROR"})


def _body(data: bytes) -> bytes | None:
    """The type fingerprint and everything after ``header_t`` (utime, agent, seq, MAC), or None if
    the datagram is too short to say (it is then decoded, and rejected, as usual)."""
    try:
        (agent_len,) = _U32.unpack_from(data, 16)
        at = 20 + agent_len + 4
        (mac_len,) = _I16.unpack_from(data, at)
    except struct.error:
        return None
    start = at + 2 + max(mac_len, 0)
    return data[:8] + data[start:] if start <= len(data) else None


_U32, _I16 = struct.Struct(">I"), struct.Struct(">h")


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
    #: The channel's state republished with the same body: ``msg`` is the one decoded before, so the
    #: UI only needs to note that the agent was heard (no transition, no new acknowledgement).
    unchanged: bool = False


class OperatorNode(Node):
    """Watches MC_STATE, HLC_STATE, TELEMETRY, HLC_ERROR and ARBITER of every agent; sends commands.

    ``settings``: the swarm's buses, topics and key under the console's own name
    (`NodeSettings.from_config` with ``agent``): a node of its own, not an agent."""

    kind = "operator"

    def __init__(
        self,
        settings: NodeSettings,
        context: Context,
        *,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(settings, context, watcher=True)  # it watches agents, flies none
        self.clock = clock
        self.wallclock = wallclock
        #: Events in arrival order, and the newest sample per channel (written on the loop thread).
        self.inbox: deque[tuple[str, bytes, float]] = deque()
        self.latest: dict[str, tuple[bytes, float]] = {}
        #: With a swarm key, what the console shows and counts as an acknowledgement must be signed
        #: by a swarm member: a forged mc_state_t would otherwise stop the resends of a command the
        #: MC never accepted. Checked (`NodeAdmission.check_datagram`) only on what is decoded (a state
        #: republished unchanged is not).
        self.rejected = 0
        self._direction_seq = 0
        self._raw_subs: list[Subscription] = []
        self._decoders: dict[str, tuple[type[Message], re.Pattern[str]]] = {}
        self._channels: dict[str, tuple[str, dict[str, str]] | None] = {}
        self._decode_log = RateLimitedLog(log)
        self.sent = 0
        self.received = 0
        self.skipped = 0
        self.decode_errors = 0
        #: Per channel, the last decoded message and its bytes after the header: a state republished
        #: unchanged (most of them, every period) is not decoded again (only its header differs).
        self._last_body: dict[str, tuple[bytes, Any]] = {}
        self.unchanged = 0

    def on_start(self) -> None:
        by_bus: dict[str, list[str]] = {}
        for topic in WATCHED_TOPICS:
            spec = self.topic_spec(topic)
            self._decoders[topic] = (spec.msg_type, re.compile(channel_regex(spec.channel)))
            by_bus.setdefault(self.settings.topic_buses(topic)[0], []).append(topic)
        for bus, topics in by_bus.items():
            # One regex per bus, not one per topic: the bus matches every datagram against every
            # pattern subscription; which topic a channel is gets worked out once per channel.
            combined = "|".join(f"(?:{_any_fields(self.topic_spec(t).channel)})" for t in topics)
            self._raw_subs.append(
                self.context.buses.subscribe(bus, combined, None, self._enqueue, regex=True)
            )

    def on_stop(self) -> None:
        for sub in self._raw_subs:
            self.context.buses.unsubscribe(sub)
        self._raw_subs.clear()

    def _enqueue(self, channel: str, data: bytes) -> None:
        """On the executor's loop: timestamp and file (the channel's kind is remembered), nothing else."""
        self.received += 1
        kind = self._channels.get(channel) or self._classify(channel)
        if kind is None:
            return
        if kind[0] in EVENTS:
            self.inbox.append((channel, data, self.clock()))
        else:
            latest = self.latest
            if channel in latest:
                self.skipped += 1  # superseded before the UI looked: never decoded
            latest[channel] = (data, self.clock())

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
        """Decode what arrived since the last call (on the UI thread): the newest message of each
        channel, and every event, oldest first."""
        decode = self.decode
        return [item for item in map(decode, self.take()) if item is not None]

    def take(self) -> list[tuple[str, bytes, float]]:
        """What arrived since the last call, undecoded ``(channel, datagram, received)``, oldest first:
        the UI decodes it with :meth:`decode` in slices, so a key press never waits behind a whole
        tick's worth of decoding."""
        # Swap, then read: a store racing the swap lands in the old table and waits one tick at most
        # (it is read below unless it came after this loop, then it is superseded by the next sample).
        latest, self.latest = self.latest, {}
        raw: list[tuple[str, bytes, float]] = [(ch, data, t) for ch, (data, t) in list(latest.items())]
        pop = self.inbox.popleft
        try:
            while True:
                raw.append(pop())
        except IndexError:
            pass
        raw.sort(key=lambda item: item[2])  # arrival order, so transitions are logged as they came
        return raw

    def deferrable(self, channel: str) -> str | None:
        """The agent of a TELEMETRY channel whose decoding may wait until it is shown, or None.

        Never with a swarm key: what the console shows must then be checked first."""
        if self.admission.checks_datagrams:
            return None
        kind = self._classify(channel)
        if kind is None or kind[0] != "TELEMETRY":
            return None
        return kind[1].get("agent")

    def decode(self, raw: tuple[str, bytes, float]) -> Incoming | None:
        """One datagram from :meth:`take` for the UI, or None (unwatched, forged, or garbage)."""
        channel, data, received = raw
        kind = self._classify(channel)
        if kind is None:
            return None
        topic, fields = kind
        body = None if topic in EVENTS else _body(data)
        if body is not None:
            last = self._last_body.get(channel)
            if last is not None and last[0] == body:
                self.unchanged += 1  # the same state again: the decoded one stands
                agent = fields.get("agent") or last[1].header.agent
                return Incoming(topic, agent, last[1], received, fields, unchanged=True)
        if self.admission.checks_datagrams:
            problem = self.admission.check_datagram(data, self.wallclock())
            if problem is not None:
                self.rejected += 1
                self._decode_log.log(
                    ("auth", channel, problem.reason),
                    logging.WARNING,
                    "ignored a message on %s: %s",
                    channel,
                    problem,
                )
                return None
        msg_type = self._decoders[topic][0]
        try:
            msg = msg_type.decode(data)
            if body is not None:
                self._last_body[channel] = (body, msg)
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
            return None
        return Incoming(topic, fields.get("agent") or msg.header.agent, msg, received, fields)

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
        return self._send(
            "DIRECTION_CMD" if target else "SWARM_DIRECTION_CMD", msg, target, self._direction_seq
        )

    def bus_summary(self) -> str:
        """'lan=udpm://…' for the topics the console watches (shown in the status bar)."""
        names = sorted({self.settings.topic_buses(t)[0] for t in WATCHED_TOPICS})
        return ", ".join(f"{n}={self.settings.buses[n]}" for n in names)
