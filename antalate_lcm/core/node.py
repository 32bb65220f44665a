"""The node base class: an explicit lifecycle, typed topics by name, timers on the executor.

A node never talks to LCM directly. It names topics (``"MC_STATE"``); its settings
(:class:`~antalate_lcm.core.node_settings.NodeSettings`, from the config) say which bus and channel each
topic uses, so moving a node to another machine is a config change (the paper's proxies). A hot path
keeps a topic's :class:`Publisher` (:meth:`Node.publisher`) and calls its ``publish``.

Security is not here but in the context's admission pipeline (:mod:`antalate_lcm.core.admission`,
docs/security.md), which each node holds its :class:`~antalate_lcm.core.admission.NodeAdmission` of: with a swarm
key, every publish has its admission sign the message after stamping its header, and every message
a node consumes through :meth:`Node.subscribe` / :meth:`Node.subscribe_all` passes its admission
(MAC, window, sender, replay, then :mod:`antalate_lcm.wire.validation`) on the executor thread before
the handler sees it; every input subscribed to passes the exposure policy first.
Messages reach handlers on the executor's loop thread straight from LCM's ``handle`` (the bus is
attached to the context's executor), so there is no queue between the socket and the node.
When an agent's nodes share a process (:meth:`Context.in_process`), its internal topics travel
between them on an in-process bus, so no datagram from the network reaches them.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from antalate_lcm.base.errors import InsecureBus as InsecureBus
from antalate_lcm.core.admission import INSECURE_REMINDER as INSECURE_REMINDER
from antalate_lcm.core.admission import RelayRefusal
from antalate_lcm.core.bus import Subscription
from antalate_lcm.core.context import INPROC_BUS as INPROC_BUS
from antalate_lcm.core.context import Context as Context
from antalate_lcm.core.context import shared_params as shared_params
from antalate_lcm.core.context import shared_value as shared_value
from antalate_lcm.core.executor import Timer
from antalate_lcm.core.node_settings import NodeSettings as NodeSettings
from antalate_lcm.core.routes import Destination, Routes
from antalate_lcm.core.timers import Ticker, divides, phase_delay
from antalate_lcm.wire import fastcodec
from antalate_lcm.wire.security import SecurityPolicy
from antalate_lcm.wire.topics import Message, TopicSpec, channel_regex, is_internal

M = TypeVar("M")


class Interference(Protocol):
    """What an experiment does to a simulated agent's traffic and timers (faults, lossy broadcasts:
    :mod:`antalate_lcm.runtime.faults`); a node without one (every real flight) pays nothing."""

    def send(self, node: Node, topic: str, msg: Message, buses: list[str], channel: str) -> bool:
        """Send the stamped ``msg`` (or not, or late, or altered) on ``buses``."""
        ...

    def receiving(self, node: Node, topic: str, handler: Callable[..., None]) -> Callable[..., None]:
        """``handler`` behind this interference: what ``node`` will consume of ``topic``."""
        ...

    def silenced(self, agent: str) -> bool:
        """Whether ``agent``'s software is dead or frozen now (its timers do not run)."""
        ...


@dataclass
class TopicMatch:
    """Where a message came from: its channel and the template fields (e.g. ``agent``) recovered."""

    channel: str
    fields: dict[str, str] = field(default_factory=dict)


class Publisher:
    """One topic's publisher on a node (:meth:`Node.publisher`): kept by a hot path, whose every
    message then costs no lookup of its topic. Its ``seq`` is the topic's counter (`Node.publish`
    counts on the same one)."""

    __slots__ = ("topic", "channel", "buses", "seq", "_node", "_senders", "_seal", "_type", "_encode")

    def __init__(self, node: Node, topic: str, destination: Destination) -> None:
        self.topic = topic
        self.channel = destination.channel
        self.buses = destination.buses
        #: The last ``header.seq`` this publisher counted.
        self.seq = 0
        self._node = node
        self._senders = destination.senders
        #: The node's admission's encoder (`NodeAdmission.seal`: signing with a key).
        self._seal = node.admission.seal
        #: Unsigned only: the type last published and its encoder (one lookup and call less).
        self._type: type | None = None
        self._encode: Callable[[Any], bytes] = self._seal

    def publish(self, msg: Message, seq: int | None = None) -> bool:
        """Stamp ``msg.header`` (time, agent, the next seq), have the node's admission sign it, send
        it on every bus of the topic; False when a bus refused it (logged by the bus).

        ``seq`` overrides the counter (a resend must carry the seq of the original: it is the
        acknowledgement key; its ``utime`` is fresh, so the receivers' replay guard lets it through).
        The admission signs (`NodeAdmission.seal`, the one place antalate signs): the MAC covers the
        final header.
        """
        node = self._node
        if seq is None:
            seq = self.seq = self.seq + 1
        # Strictly increasing per node, so two messages in one microsecond are not a "replay".
        utime = int(node.wallclock() * 1_000_000)
        if utime <= node._last_utime:
            utime = node._last_utime + 1
        node._last_utime = utime
        header = msg.header
        header.utime = utime
        header.agent = node.agent
        header.seq = seq
        if node.interference is not None:
            return node.interference.send(node, self.topic, msg, self.buses, self.channel)
        if type(msg) is self._type:
            data = self._encode(msg)
        else:
            data = self._seal(msg)
            if self._seal is fastcodec.encode:  # the plain encoder, never a key's seal (it signs)
                self._type, self._encode = type(msg), fastcodec.encoder(type(msg))
        channel = self.channel
        ok = True
        for bus, send in self._senders:
            try:
                send(channel, data)
            except OSError as exc:
                ok = node.context.buses.publish_failed(bus, channel, exc) and ok
        return ok


class Node:
    """Base class of MC, HLC, BMA, OSC and the operator console.

    Lifecycle: construct (no I/O) → :meth:`start` (subscribe, start timers, ``on_start``) →
    :meth:`stop` (cancel timers, unsubscribe, then ``on_stop``). Callbacks run on the executor thread.

    ``settings``: what the node reads of the configuration (its name on the buses, its topics' channels
    and buses, its ``[security]``); an agent's node keeps its whole config for its own logic itself.
    Signing, verification, validation and the exposure policy are the context's admission
    pipeline; :attr:`admission` is this node's (`Context.admission`), :attr:`routes` its topics'
    channels and buses. ``watcher``: the node watches agents rather than flying one (the operator
    console, the scripted operator): it may consume agents' state from a network bus without a swarm
    key (what it reads moves no vehicle).
    """

    kind = "node"
    #: An experiment's faults and lossy broadcasts, set before :meth:`start` (None: none).
    interference: Interference | None = None
    #: Wall clock for ``header.utime`` and the replay window (tests and the console inject theirs).
    wallclock: Callable[[], float] = staticmethod(time.time)

    def __init__(
        self, settings: NodeSettings, context: Context, *, name: str | None = None, watcher: bool = False
    ) -> None:
        self.settings = settings
        self.context = context
        self.agent = settings.agent
        self.name = name or self.kind
        self.log = logging.getLogger(f"antalate.{self.kind}.{self.agent}")
        if context.executor.sim is not None:  # simulated time: headers and the replay window on it
            self.wallclock = context.executor.wallclock
        #: The topics' channels and buses (`Routes`).
        self.routes = Routes(settings, context)
        #: `Node.publisher`'s handles by topic (and template fields), read by every `publish`.
        self._publishers: dict[Any, Publisher] = {}
        self._subs: list[Subscription] = []
        #: subscribe_all's pattern subscription -> its own-channel subscription (unsubscribed together).
        self._companions: dict[Subscription, Subscription] = {}
        self._timers: list[Timer] = []
        #: The agent's shared timers this node has jobs on (`ticker`).
        self._tickers: list[Ticker] = []
        self.started = False
        self._last_utime = 0
        self._now: Callable[[], float] = context.executor.clock  # `now` without two lookups
        self.admission = context.admission.for_node(self, watcher=watcher)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self.started:
            return
        self.started = True
        self.admission.restart()  # a restarted node warns (and schedules its reminder) afresh
        self.context.executor.run_sync(self.on_start)

    def stop(self) -> None:
        if not self.started:
            return
        self.started = False

        def shutdown() -> None:
            # Timers and subscriptions go first, on the executor thread (so none is mid-run): a
            # timer that ran after on_stop would meet a closed adapter (a false LINK_LOST).
            for ticker in self._tickers:
                # The agent's other nodes keep their jobs on it (an MC watching for its HLC).
                if ticker.remove(self):
                    ticker.timer.cancel()
                    if self.context.tickers.get(self.agent) is ticker:
                        del self.context.tickers[self.agent]
            shared = [ticker.timer for ticker in self._tickers]
            self._tickers.clear()
            for timer in self._timers:
                if not any(timer is t for t in shared):
                    timer.cancel()
            for sub in self._subs:
                self.context.buses.unsubscribe(sub)
            self._timers.clear()
            self._subs.clear()
            self._companions.clear()
            self.on_stop()

        self.context.executor.run_sync(shutdown)

    def on_start(self) -> None:
        """Subscribe and create timers here (runs on the executor thread)."""

    # ------------------------------------------------------------------ admission (core/admission.py)
    @property
    def security(self) -> SecurityPolicy:
        """The node's ``[security]`` keys and window."""
        return self.admission.policy

    def on_stop(self) -> None:
        """Release what ``on_start`` acquired beyond subscriptions and timers."""

    # ------------------------------------------------------------------ topics (core/routes.py)
    def topic_spec(self, topic: str) -> TopicSpec:
        return self.routes.spec(topic)

    def channel(self, topic: str, **fields: str) -> str:
        return self.routes.channel(topic, **fields)

    def publisher(self, topic: str, **fields: str) -> Publisher:
        """The publisher of ``topic`` (its channel with ``fields``): made on first use, the same
        handle afterwards (and the one :meth:`publish` uses, so they count one ``seq``)."""
        key = (topic, tuple(sorted(fields.items()))) if fields else topic
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = Publisher(self, topic, self.routes.destination(topic, fields))
        return pub

    def publish(
        self,
        topic: str,
        msg: Message,
        *,
        seq: int | None = None,
        **fields: str,
    ) -> bool:
        """Stamp ``msg.header`` (time, agent, per-topic seq), sign it with the swarm key, send it on
        every bus of the topic: :meth:`Publisher.publish` of the topic's :meth:`publisher`."""
        pub = self._publishers.get((topic, tuple(sorted(fields.items()))) if fields else topic)
        if pub is None:
            pub = self.publisher(topic, **fields)
        return pub.publish(msg, seq)

    def outgoing(self, msg_type: type[M]) -> M:
        """A message of ``msg_type`` to fill and hand to :meth:`publish` at once: the context's one
        (see `Context.scratch`), or a fresh one for a signing node (the MAC goes into its header;
        an HMAC costs more than the message) and where an experiment's interference may hold on to
        what is sent. Its fields keep what the last user wrote: fill every one."""
        if self.interference is None and not self.admission.signs:
            scratch = self.context.scratch
            msg = scratch.get(msg_type)
            if msg is None:
                msg = scratch[msg_type] = msg_type()
            return msg
        return msg_type()

    def relay(self, topic: str, msg: Any, *, signed: bool, seq: int | None = None) -> RelayRefusal | None:
        """Publish an operator's command that reached this agent another way (the station, through
        the OSC), if its admission lets it through (`NodeAdmission.vet_relay`); else why not (counted by the caller).

        ``signed``: it goes out exactly as the operator signed it (header and MAC untouched, no
        signature of this node's); unsigned (an agent without a swarm key), as this node's own
        message with ``seq``."""
        refusal = self.admission.vet_relay(msg, signed=signed, channel=self.channel(topic))
        if refusal is not None:
            return refusal
        if not signed:
            self.publish(topic, msg, seq=seq)
            return None
        data = msg.encode()
        channel = self.channel(topic)
        for bus in self.routes.publish_buses(topic):
            self.context.buses.publish(bus, channel, data)
        return None

    def subscribe(self, topic: str, handler: Callable[[Any], None], **fields: str) -> Subscription:
        """Deliver this agent's ``topic`` (decoded, authenticated, validated) to ``handler`` on the
        executor thread."""
        if self.interference is not None:
            handler = self.interference.receiving(self, topic, handler)
        spec = self.topic_spec(topic)
        bus = self.routes.subscribe_bus(topic)
        self.admission.check_exposure(topic, bus)
        channel = self.channel(topic, **fields)
        sender = fields.get("agent", self.agent) if is_internal(topic) and "{agent}" in spec.channel else None
        on_message: Callable[[Any], None] | None = None
        if not self.admission.needs_admission(spec.msg_type):
            # Nothing to admit (no key, a type with no input check): the bus calls the handler
            # itself (`Subscription.on_message`), two calls and a closure's cells less on every
            # message of a node's hot path (benchmarks/bus.py, node to node).
            on_message = handler

            def deliver(_channel: str, msg: Any) -> None:  # on the executor's loop thread
                handler(msg)

        else:
            admit = self.admission.admit

            def deliver(_channel: str, msg: Any) -> None:  # on the executor's loop thread
                if admit(channel, msg, sender):
                    handler(msg)

        sub = self.context.buses.subscribe(bus, channel, spec.msg_type, deliver, on_message=on_message)
        self._subs.append(sub)
        return sub

    def subscribe_all(
        self, topic: str, handler: Callable[[Any, TopicMatch], None], **fields: str
    ) -> Subscription:
        """Deliver ``topic`` from every agent (template fields not given match anything).

        Other agents' messages come from the configured bus, never the in-process one: peers may be
        other processes. This agent's own channel, when the pattern covers it, is delivered once,
        from where :meth:`subscribe` takes it (the in-process bus in one process): the copy that
        also comes back over the network (multicast loops back; the same LCM instance's exact and
        pattern subscriptions decode separately) is dropped by channel before any check, so the
        replay guard never sees this agent's message twice (it logged "replayed or out of order").
        """
        if self.interference is not None:
            handler = self.interference.receiving(self, topic, handler)
        spec = self.topic_spec(topic)
        bus = self.settings.topic_buses(topic)[0]
        self.admission.check_exposure(topic, bus)
        pattern = re.compile(channel_regex(spec.channel, **fields))
        bound = is_internal(topic) and "{agent}" in spec.channel
        own = self.channel(topic, **fields) if "{agent}" in spec.channel else None
        if own is not None and not pattern.fullmatch(own):
            own = None
        # Channel -> match, so a steady stream of known channels costs no regex per message.
        matches: dict[str, TopicMatch] = {}
        admit = self.admission.admit

        def deliver(channel: str, msg: Any) -> None:  # on the executor's loop thread
            if channel == own:
                return
            match = matches.get(channel)
            if match is None:
                m = pattern.fullmatch(channel)
                match = TopicMatch(channel, m.groupdict() if m else {})
                if len(matches) < 100_000:
                    matches[channel] = match
            if admit(channel, msg, match.fields.get("agent") if bound else None):
                handler(msg, match)

        sub = self.context.buses.subscribe(bus, pattern.pattern, spec.msg_type, deliver, regex=True)
        self._subs.append(sub)
        if own is not None:
            m = pattern.fullmatch(own)
            own_match = TopicMatch(own, m.groupdict() if m else {})
            own_bus = self.routes.subscribe_bus(topic)
            if own_bus != bus:
                self.admission.check_exposure(topic, own_bus)
            sender = self.agent if bound else None

            def deliver_own(_channel: str, msg: Any) -> None:  # on the executor's loop thread
                if admit(own_match.channel, msg, sender):
                    handler(msg, own_match)

            companion = self.context.buses.subscribe(own_bus, own, spec.msg_type, deliver_own)
            self._subs.append(companion)
            self._companions[sub] = companion
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        companion = self._companions.pop(sub, None)
        if companion is not None:  # subscribe_all's own-channel half goes with it
            self.unsubscribe(companion)
        self.context.buses.unsubscribe(sub)
        if sub in self._subs:
            self._subs.remove(sub)

    # ------------------------------------------------------------------ time
    def create_timer(
        self, period: float, fn: Callable[[], Any], *, first_delay: float | None = None
    ) -> Timer:
        fn = self._interfered(fn)
        timer = self.context.executor.create_timer(period, fn, first_delay=first_delay)
        self._timers.append(timer)
        return timer

    def _interfered(self, fn: Callable[[], Any]) -> Callable[[], Any]:
        """``fn``, skipped while the experiment holds this agent dead or frozen."""
        interference = self.interference
        if interference is None:
            return fn
        agent = self.agent

        def run() -> Any:
            return None if interference.silenced(agent) else fn()

        return run

    def call_later(self, delay: float, fn: Callable[[], Any]) -> Timer:
        fn = self._interfered(fn)

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
        return self._now()

    def state_publisher(
        self, topic: str, build: Callable[[], Any], hz: float, *, periodic: bool = True, **fields: str
    ) -> Callable[[], None]:
        """Publish ``build()`` every ``1/hz`` s, and whenever the returned function is called.

        State messages go out periodically as well as on change (docs/design.md §4) so a node that starts
        late or loses a packet converges within one period. ``periodic=False``: the caller runs the
        returned function every ``1/hz`` s itself, from a timer it already has (see `ticker`).
        """

        publish = self.publisher(topic, **fields).publish

        def publish_now() -> None:
            publish(build())

        if periodic:
            self.create_timer(1.0 / hz, publish_now, first_delay=self.first_delay(1.0 / hz))
        return publish_now

    def ticker(
        self,
        hz: float,
        jobs: list[tuple[float, Callable[[], Any]]],
        *,
        clock: Callable[[], float] | None = None,
    ) -> None:
        """Run each ``(rate, fn)`` of ``jobs`` at its rate, on as few timers as the rates allow.

        A job whose rate divides ``hz`` (the first job's, the fastest) runs on one timer (a
        `Ticker`), right after the jobs before it, on the runs where its own period has come round;
        any other job gets a timer of its own. The agent's nodes share that timer when their rates
        divide its rate: the MC's 10 and 5 Hz jobs run on the HLC's 20 Hz timer. A thousand
        simulated agents in one process ran 50 timers a second each (HLC control, telemetry and
        state, MC tick and state), then 30 (one per node), now 20, and a telemetry message built a
        tick after the snapshot it reports found it out of the cache.

        A shared job keeps its own due time, not a count of runs: when a loaded executor skips
        runs of the timer (it never bursts to catch up), the job still runs at its rate on the
        runs that remain, as its own timer would. Each job's exception is logged on its own.
        ``clock``: the time of each run (the run's due time unless a test gives its own); a
        ticker with a clock of its own is this node's alone.
        """
        tickers = self.context.tickers
        host = tickers.get(self.agent) if clock is None else None
        if host is not None and host.takes(jobs):
            host.add(self, [(rate, self._interfered(fn)) for rate, fn in jobs], self.log)
            self._tickers.append(host)
            return
        period = 1.0 / hz
        ticker = Ticker(hz)
        shared: list[tuple[float, Callable[[], Any]]] = []
        for rate, fn in jobs:
            if divides(hz, rate):
                shared.append((rate, self._interfered(fn)))
            else:
                self.create_timer(1.0 / rate, fn, first_delay=self.first_delay(1.0 / rate))
        if not shared:
            return
        ticker.add(self, shared, self.log)
        run = ticker.run
        tick = run if clock is None else lambda: run(clock())
        # Straight on the executor: its jobs are wrapped one by one (`_interfered`), as they may
        # be other nodes' too.
        timer = self.context.executor.create_timer(period, tick, first_delay=self.first_delay(period))
        ticker.timer = timer
        self._timers.append(timer)
        if clock is None:
            self._tickers.append(ticker)
            if host is None:
                tickers[self.agent] = ticker

    def first_delay(self, period: float) -> float:
        """When a periodic timer of this agent first runs (`phase_delay`: within one ``period``, at
        a phase fixed by the agent's name and the run's seed)."""
        return phase_delay(period, self.agent, self.context.seed)
