"""The node base class: an explicit lifecycle, typed topics by name, timers on the executor.

A node never talks to LCM directly. It names topics (``"MC_STATE"``); the config says which bus and
channel each topic uses, so moving a node to another machine is a config change (the paper's proxies).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from antalate_lcm.bus import Bus, Subscription
from antalate_lcm.config import Config
from antalate_lcm.executor import Executor, Timer
from antalate_lcm.topics import TopicSpec, channel_regex


@dataclass
class Context:
    """What the nodes of one process share: the bus connections and the executor thread."""

    bus: Bus
    executor: Executor

    @classmethod
    def create(cls, config: Config) -> Context:
        return cls(Bus(config.buses), Executor())

    def close(self) -> None:
        self.executor.stop()
        self.bus.close()


def now_utime() -> int:
    return int(time.time() * 1_000_000)


@dataclass
class _Publisher:
    buses: list[str]
    channel: str
    seq: int = 0


@dataclass
class TopicMatch:
    """Where a message came from: its channel and the template fields (e.g. ``agent``) recovered."""

    channel: str
    fields: dict[str, str] = field(default_factory=dict)


class Node:
    """Base class of MC, HLC, BMA, OSC and the operator console.

    Lifecycle: construct (no I/O) → :meth:`start` (subscribe, start timers, ``on_start``) →
    :meth:`stop` (``on_stop``, cancel timers, unsubscribe). Callbacks run on the executor thread.
    """

    kind = "node"

    def __init__(self, config: Config, context: Context, *, name: str | None = None) -> None:
        self.config = config
        self.context = context
        self.agent = config.agent.name
        self.name = name or self.kind
        self.log = logging.getLogger(f"antalate.{self.kind}.{self.agent}")
        self._specs = config.topic_specs()
        self._publishers: dict[tuple[str, tuple[tuple[str, str], ...]], _Publisher] = {}
        self._subs: list[Subscription] = []
        self._timers: list[Timer] = []
        self.started = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self.started:
            return
        self.started = True
        self.context.executor.run_sync(self.on_start)

    def stop(self) -> None:
        if not self.started:
            return
        self.started = False
        try:
            self.context.executor.run_sync(self.on_stop)
        finally:
            for timer in self._timers:
                timer.cancel()
            for sub in self._subs:
                self.context.bus.unsubscribe(sub)
            self._timers.clear()
            self._subs.clear()

    def on_start(self) -> None:
        """Subscribe and create timers here (runs on the executor thread)."""

    def on_stop(self) -> None:
        """Release what ``on_start`` acquired beyond subscriptions and timers."""

    # ------------------------------------------------------------------ topics
    def topic_spec(self, topic: str) -> TopicSpec:
        try:
            return self._specs[topic]
        except KeyError:
            raise KeyError(f"unknown topic {topic!r}; known: {', '.join(self._specs)}") from None

    def channel(self, topic: str, **fields: str) -> str:
        return self.topic_spec(topic).channel.format(**{"agent": self.agent, **fields})

    def publish(
        self,
        topic: str,
        msg: Any,
        *,
        seq: int | None = None,
        before_encode: Callable[[Any], None] | None = None,
        **fields: str,
    ) -> bool:
        """Stamp ``msg.header`` (time, agent, per-topic seq) and send it on every bus of the topic.

        ``seq`` overrides the counter (a resend must carry the seq of the original: it is the
        acknowledgement key); ``before_encode`` runs on the stamped message (to sign it).
        """
        key = (topic, tuple(sorted(fields.items())))
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = _Publisher(self.config.topic_buses(topic), self.channel(topic, **fields))
        if seq is None:
            pub.seq += 1
            seq = pub.seq
        header = msg.header
        header.utime = now_utime()
        header.agent = self.agent
        header.seq = seq
        if before_encode is not None:
            before_encode(msg)
        data = msg.encode()
        ok = True
        for bus in pub.buses:
            ok = self.context.bus.publish(bus, pub.channel, data) and ok
        return ok

    def subscribe(self, topic: str, handler: Callable[[Any], None], **fields: str) -> Subscription:
        """Deliver this agent's ``topic`` (decoded) to ``handler`` on the executor thread."""
        spec = self.topic_spec(topic)
        bus = self.config.topic_buses(topic)[0]
        post = self.context.executor.call_soon
        sub = self.context.bus.subscribe(
            bus, self.channel(topic, **fields), spec.msg_type, lambda _ch, msg: post(handler, msg)
        )
        self._subs.append(sub)
        return sub

    def subscribe_all(self, topic: str, handler: Callable[[Any, TopicMatch], None], **fields: str) -> Subscription:
        """Deliver ``topic`` from every agent (template fields not given match anything)."""
        spec = self.topic_spec(topic)
        bus = self.config.topic_buses(topic)[0]
        pattern = re.compile(channel_regex(spec.channel, **fields))
        post = self.context.executor.call_soon

        def deliver(channel: str, msg: Any) -> None:
            m = pattern.fullmatch(channel)
            post(handler, msg, TopicMatch(channel, m.groupdict() if m else {}))

        sub = self.context.bus.subscribe(bus, pattern.pattern, spec.msg_type, deliver, regex=True)
        self._subs.append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        self.context.bus.unsubscribe(sub)
        if sub in self._subs:
            self._subs.remove(sub)

    # ------------------------------------------------------------------ time
    def create_timer(self, period: float, fn: Callable[[], Any], *, first_delay: float | None = None) -> Timer:
        timer = self.context.executor.create_timer(period, fn, first_delay=first_delay)
        self._timers.append(timer)
        return timer

    def call_later(self, delay: float, fn: Callable[[], Any]) -> Timer:
        def fire() -> None:
            if timer in self._timers:  # a one-shot leaves the list once it ran, so it never grows
                self._timers.remove(timer)
            fn()

        timer = self.context.executor.call_later(delay, fire)
        self._timers.append(timer)
        return timer

    @property
    def now(self) -> float:
        """Monotonic seconds on the executor's clock (what state machines are given)."""
        return self.context.executor.clock()

    def state_publisher(self, topic: str, build: Callable[[], Any], hz: float, **fields: str) -> Callable[[], None]:
        """Publish ``build()`` every ``1/hz`` s, and whenever the returned function is called.

        State messages go out periodically as well as on change (docs/design.md §4) so a node that starts
        late or loses a packet converges within one period.
        """

        def publish_now() -> None:
            self.publish(topic, build(), **fields)

        self.create_timer(1.0 / hz, publish_now)
        return publish_now
