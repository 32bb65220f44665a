"""The node base class: an explicit lifecycle, typed topics by name, timers on the executor.

A node never talks to LCM directly. It names topics (``"MC_STATE"``); the config says which bus and
channel each topic uses, so moving a node to another machine is a config change (the paper's proxies).

Security lives here, in one place (docs/security.md): with a swarm key, :meth:`Node.publish` signs
every message after stamping its header, and every message a node consumes through
:meth:`Node.subscribe` / :meth:`Node.subscribe_all` is authenticated (MAC, window, sender, replay)
and validated (:mod:`antalate_lcm.wire.validation`) on the executor thread before the handler sees it.
Messages reach handlers on the executor's loop thread straight from LCM's ``handle`` (the bus is
attached to the context's executor), so there is no queue between the socket and the node.
When an agent's nodes share a process (:meth:`Context.in_process`), its internal topics travel
between them on an in-process bus, so no datagram from the network reaches them.
"""

from __future__ import annotations

import logging
import math
import re
import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.base.errors import InsecureBus as InsecureBus
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.bus import Bus, Subscription
from antalate_lcm.core.config import Config
from antalate_lcm.core.executor import Executor, Timer
from antalate_lcm.wire import validation
from antalate_lcm.wire.fastcodec import encode as fast_encode
from antalate_lcm.wire.security import (
    Authenticator,
    HighWaterStore,
    ReplayGuard,
    SecurityPolicy,
    default_state_dir,
    network_reachable,
    signed_bytes,
)
from antalate_lcm.wire.topics import (
    OPERATOR_INPUTS,
    PERSISTED_TYPES,
    Message,
    TopicSpec,
    channel_regex,
    is_internal,
)

#: The bus name of :meth:`Context.in_process` (memq://, one per process).
INPROC_BUS = "_inproc"
#: Phases a period is split into to spread the agents' periodic timers (Node.first_delay).
_PHASES = 1000
#: s between the reminders an insecure node logs.
INSECURE_REMINDER = 60.0
M = TypeVar("M")


#: Equal immutable values (a node's machine parameters) -> the one instance of them (`shared_value`).
_SHARED: dict[Any, Any] = {}


def shared_value(value: M) -> M:
    """The process's one instance equal to ``value`` (hashable, immutable): a thousand agents with one
    config read the same parameters object on every tick, one object in the cache instead of a
    thousand copies."""
    return _SHARED.setdefault(value, value)  # type: ignore[no-any-return]


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
class Context:
    """What the nodes of one process share: the bus connections and the executor (its one loop).

    ``inproc_bus`` names a memq:// bus that carries the agents' internal topics between the nodes
    of this process (see :meth:`in_process`); None when each node runs in its own process.
    """

    bus: Bus
    executor: Executor
    inproc_bus: str | None = None
    #: Every agent of the swarm runs in this process (``antalate agent`` without ``--processes``,
    #: the demo): a process-local bus (memq://) then reaches every peer a behavior asks for.
    whole_swarm: bool = False
    #: Buses whose missing swarm key a node of this process has already warned of: a thousand
    #: agents in one process (``antalate agent --agents 1000``) would say it a thousand times and
    #: bury every other line of the start.
    open_warned: set[str] = field(default_factory=set, repr=False)
    #: The run's seed (``antalate run --seed``, and always on simulated time): the agents' timer
    #: phases and the behaviors' random draws (``BehaviorContext.seed``) derive from it, so a run
    #: is a function of it. None: phases fixed by the agents' names, behaviors seed as they like.
    seed: int | None = None
    #: One outgoing message of each type for the nodes of this context that do not sign (`Node.outgoing`): a node
    #: refills it and publish encodes it at once, on the loop's one thread, so a thousand agents'
    #: 20 messages a second touch one object (hot in the cache), not a thousand of their own.
    scratch: dict[type, Any] = field(default_factory=dict, repr=False)
    #: Buses -> their (name, send) pairs, shared by every publisher of the context on those buses.
    senders: dict[tuple[str, ...], list[tuple[str, Callable[[str, bytes], None]]]] = field(
        default_factory=dict, repr=False
    )

    def __post_init__(self) -> None:
        self.bus.attach(self.executor)  # the bus's descriptors are read on the nodes' loop

    @classmethod
    def create(cls, config: Config) -> Context:
        return cls(Bus(config.buses), Executor())

    @classmethod
    def in_process(
        cls, buses: Mapping[str, str], *, whole_swarm: bool = False, executor: Executor | None = None
    ) -> Context:
        """A context for every node of one or more agents in this process (``antalate agent``, demo).

        Internal topics (MC_STATE, HLC_STATE, VELOCITY_CMD, ...) are delivered between this
        process's nodes over memq:// and still published on the configured buses for the operator
        and the tools; a spoofed datagram on the LAN never reaches the MC or the HLC.
        ``executor``: the loop to run them on (one on simulated time: ``antalate run --speed``).
        """
        if INPROC_BUS in buses:
            raise AntalateError(f"bus name {INPROC_BUS!r} is reserved for the in-process bus")
        return cls(
            Bus({**buses, INPROC_BUS: "memq://"}),
            executor or Executor(),
            inproc_bus=INPROC_BUS,
            whole_swarm=whole_swarm,
        )

    def close(self) -> None:
        self.executor.stop()
        self.bus.close()


@dataclass
class _Publisher:
    buses: list[str]
    channel: str
    #: Each bus's send function (`Bus.sender`), resolved once: 20 publishes a second per agent.
    senders: list[tuple[str, Callable[[str, bytes], None]]]
    seq: int = 0


@dataclass
class TopicMatch:
    """Where a message came from: its channel and the template fields (e.g. ``agent``) recovered."""

    channel: str
    fields: dict[str, str] = field(default_factory=dict)


class Node:
    """Base class of MC, HLC, BMA, OSC and the operator console.

    Lifecycle: construct (no I/O) → :meth:`start` (subscribe, start timers, ``on_start``) →
    :meth:`stop` (cancel timers, unsubscribe, then ``on_stop``). Callbacks run on the executor thread.

    A node whose ``kind`` is ``"operator"`` watches agents rather than flying one: it may consume
    agents' state from a network bus without a swarm key (what it reads moves no vehicle).
    """

    kind = "node"
    #: An experiment's faults and lossy broadcasts, set before :meth:`start` (None: none).
    interference: Interference | None = None
    #: Wall clock for ``header.utime`` and the replay window (tests and the console inject theirs).
    wallclock: Callable[[], float] = staticmethod(time.time)

    def __init__(self, config: Config, context: Context, *, name: str | None = None) -> None:
        self.config = config
        self.context = context
        self.agent = config.agent.name
        self.name = name or self.kind
        self.log = logging.getLogger(f"antalate.{self.kind}.{self.agent}")
        if context.executor.sim is not None:  # simulated time: headers and the replay window on it
            self.wallclock = context.executor.wallclock
        self._specs = config.topic_specs()
        self._publishers: dict[Any, _Publisher] = {}
        self._subs: list[Subscription] = []
        #: subscribe_all's pattern subscription -> its own-channel subscription (unsubscribed together).
        self._companions: dict[Subscription, Subscription] = {}
        self._timers: list[Timer] = []
        self.started = False
        sec = config.security
        self.security = SecurityPolicy(sec.swarm_key, tuple(sec.previous_keys), sec.window)
        self._auth: Authenticator | None = None
        self._last_utime = 0
        self._invalid_log = RateLimitedLog(self.log, period=10.0)
        #: Messages dropped by input validation (the authenticator counts its own rejections).
        self.invalid = 0
        self._insecure: dict[str, str] = {}
        self._open_inputs: dict[str, str] = {}

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self.started:
            return
        self.started = True
        self._insecure.clear()  # a restarted node warns (and schedules its reminder) afresh
        self._open_inputs.clear()
        self.context.executor.run_sync(self.on_start)

    def stop(self) -> None:
        if not self.started:
            return
        self.started = False

        def shutdown() -> None:
            # Timers and subscriptions go first, on the executor thread (so none is mid-run): a
            # timer that ran after on_stop would meet a closed adapter (a false LINK_LOST).
            for timer in self._timers:
                timer.cancel()
            for sub in self._subs:
                self.context.bus.unsubscribe(sub)
            self._timers.clear()
            self._subs.clear()
            self._companions.clear()
            self.on_stop()

        self.context.executor.run_sync(shutdown)

    def on_start(self) -> None:
        """Subscribe and create timers here (runs on the executor thread)."""

    # ------------------------------------------------------------------ security
    @property
    def authenticator(self) -> Authenticator | None:
        """The checks every consumed message passes with a swarm key (None without one)."""
        if self._auth is None and self.security.enabled:
            store = None
            state_dir = self.replay_state_dir()
            if state_dir is not None:
                store = HighWaterStore(state_dir / f"{self.agent}.{self.name}.replay.json")
            self._auth = Authenticator(
                self.security,
                self.log,
                replay_guard=ReplayGuard(store, PERSISTED_TYPES),
                wallclock=self.wallclock,
            )
        return self._auth

    def replay_state_dir(self) -> Path | None:
        """Where this node keeps its replay memory: ``[security] state_dir``, else the user's state
        directory, else (every bus memq:// or file://, nothing survives the process anyway) nowhere.
        On simulated time nowhere: every run's clock starts at the same date, and a memory of the
        last run would refuse the next one's messages as replays."""
        if self.context.executor.sim is not None:
            return None
        if self.config.security.state_dir:
            return Path(self.config.security.state_dir).expanduser()
        if any(network_reachable(url) for url in self.config.buses.values()):
            return default_state_dir()
        return None

    def _check_exposure(self, topic: str, bus: str) -> None:
        """Refuse (or, with ``insecure``, loudly accept) an unauthenticated input from the network."""
        url = self.context.bus.urls.get(bus, "")
        if self.security.enabled or not network_reachable(url):
            return
        if topic in OPERATOR_INPUTS:
            warned = self.context.open_warned
            if bus not in warned:
                warned.add(bus)
                self.log.warning(
                    "no [security] swarm_key: anyone who can send to bus %r (%s) can command %s, and "
                    "every other agent of this process without a key (take off, land, steer); said "
                    "once per bus; see docs/security.md",
                    bus,
                    url,
                    self.agent,
                )
            elif not self._open_inputs:
                self.log.debug("no [security] swarm_key: bus %r can command %s", bus, self.agent)
            self._open_inputs[topic] = bus
            return
        if self.kind == "operator" or not is_internal(topic):
            return
        if not self.config.security.insecure:
            raise InsecureBus(
                f"{self.kind} of {self.agent} would take {topic} from bus {bus!r} ({url}), which any host on "
                "the network can send to, with no swarm key: set [security] swarm_key (`antalate keygen`) "
                "in every config of the swarm, or run the agent's nodes in one process (`antalate agent`, "
                "internal topics then stay in memory); [security] insecure = true accepts the risk"
            )
        first = not self._insecure
        self._insecure[topic] = bus
        if first:
            self._warn_insecure()
            self.create_timer(INSECURE_REMINDER, self._warn_insecure, first_delay=INSECURE_REMINDER)

    def _warn_insecure(self) -> None:
        where = ", ".join(f"{t} on {b!r}" for t, b in sorted(self._insecure.items()))
        self.log.warning(
            "INSECURE ([security] insecure = true, no swarm key): anyone on the network can spoof %s of %s "
            "(launch it, fly it, ground it, put it in ERROR)",
            where,
            self.agent,
        )

    def _admit(self, channel: str, msg: Any, expected_sender: str | None) -> bool:
        """Authenticate (with a key) and validate one consumed message; False = dropped, logged."""
        auth = self.authenticator
        if auth is not None and auth.check(msg, channel, expected_sender=expected_sender) is not None:
            return False
        problem = validation.problem(msg)
        if problem is not None:
            self.invalid += 1
            self._invalid_log.log(
                ("invalid", channel),
                logging.WARNING,
                "rejected %s on %s from %r seq %d: %s (%d invalid so far)",
                type(msg).__name__,
                channel,
                msg.header.agent,
                msg.header.seq,
                problem,
                self.invalid,
            )
            return False
        return True

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
        msg: Message,
        *,
        seq: int | None = None,
        **fields: str,
    ) -> bool:
        """Stamp ``msg.header`` (time, agent, per-topic seq), sign it with the swarm key, send it on
        every bus of the topic.

        ``seq`` overrides the counter (a resend must carry the seq of the original: it is the
        acknowledgement key; its ``utime`` is fresh, so the receivers' replay guard lets it through).
        This is the one place antalate signs: the MAC covers the final header.
        """
        pub = self._publishers.get((topic, tuple(sorted(fields.items()))) if fields else topic)
        if pub is None:
            pub = self._publisher(topic, fields)
        if seq is None:
            pub.seq += 1
            seq = pub.seq
        # Strictly increasing per node, so two messages in one microsecond are not a "replay".
        utime = int(self.wallclock() * 1_000_000)
        if utime <= self._last_utime:
            utime = self._last_utime + 1
        self._last_utime = utime
        header = msg.header
        header.utime = utime
        header.agent = self.agent
        header.seq = seq
        if self.interference is not None:
            return self.interference.send(self, topic, msg, pub.buses, pub.channel)
        key = self.security.key  # SecurityPolicy.enabled is bool(key), without a property call
        data = signed_bytes(msg, key) if key else fast_encode(msg)
        channel = pub.channel
        ok = True
        for bus, send in pub.senders:
            try:
                send(channel, data)
            except OSError as exc:
                ok = self.context.bus.publish_failed(bus, channel, exc) and ok
        return ok

    def _publisher(self, topic: str, fields: dict[str, str]) -> _Publisher:
        buses = self._publish_buses(topic)
        bus = self.context.bus
        shared = self.context.senders
        senders = shared.get(tuple(buses))
        if senders is None:
            senders = shared[tuple(buses)] = [(name, bus.sender(name)) for name in buses]
        pub = _Publisher(buses, self.channel(topic, **fields), senders)
        self._publishers[(topic, tuple(sorted(fields.items()))) if fields else topic] = pub
        return pub

    def outgoing(self, msg_type: type[M]) -> M:
        """A message of ``msg_type`` to fill and hand to :meth:`publish` at once: the context's one
        (see `Context.scratch`), or a fresh one for a signing node (the MAC goes into its header;
        an HMAC costs more than the message) and where an experiment's interference may hold on to
        what is sent. Its fields keep what the last user wrote: fill every one."""
        if self.interference is None and not self.security.key:
            scratch = self.context.scratch
            msg = scratch.get(msg_type)
            if msg is None:
                msg = scratch[msg_type] = msg_type()
            return msg
        return msg_type()

    def seal(self, msg: Message) -> bytes:
        """The bytes of a stamped message: signed with the swarm key if there is one."""
        key = self.security.key
        return signed_bytes(msg, key) if key else fast_encode(msg)

    def _publish_buses(self, topic: str) -> list[str]:
        """The topic's buses (plus the in-process bus for an internal topic), one per distinct URL."""
        names = self.config.topic_buses(topic)
        inproc = self.context.inproc_bus
        if inproc is not None and is_internal(topic):
            names = [inproc, *names]
        out: list[str] = []
        seen: set[str] = set()
        for name in names:
            url = self.context.bus.urls.get(name, name)
            if url not in seen:  # two names for one URL are one LCM instance: send once
                seen.add(url)
                out.append(name)
        return out

    def _subscribe_bus(self, topic: str) -> str:
        inproc = self.context.inproc_bus
        if inproc is not None and is_internal(topic):
            return inproc
        return self.config.topic_buses(topic)[0]

    def subscribe(self, topic: str, handler: Callable[[Any], None], **fields: str) -> Subscription:
        """Deliver this agent's ``topic`` (decoded, authenticated, validated) to ``handler`` on the
        executor thread."""
        if self.interference is not None:
            handler = self.interference.receiving(self, topic, handler)
        spec = self.topic_spec(topic)
        bus = self._subscribe_bus(topic)
        self._check_exposure(topic, bus)
        channel = self.channel(topic, **fields)
        sender = fields.get("agent", self.agent) if is_internal(topic) and "{agent}" in spec.channel else None
        if self.authenticator is None and not validation.needs_check(spec.msg_type):
            # Nothing to admit (no key, a type with no input check): straight to the handler, one
            # call less on every message of a node's hot path (benchmarks/bus.py, node to node).
            def deliver(_channel: str, msg: Any) -> None:  # on the executor's loop thread
                handler(msg)

        else:
            admit = self._admit

            def deliver(_channel: str, msg: Any) -> None:  # on the executor's loop thread
                if admit(channel, msg, sender):
                    handler(msg)

        sub = self.context.bus.subscribe(bus, channel, spec.msg_type, deliver)
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
        bus = self.config.topic_buses(topic)[0]
        self._check_exposure(topic, bus)
        pattern = re.compile(channel_regex(spec.channel, **fields))
        bound = is_internal(topic) and "{agent}" in spec.channel
        own = self.channel(topic, **fields) if "{agent}" in spec.channel else None
        if own is not None and not pattern.fullmatch(own):
            own = None
        # Channel -> match, so a steady stream of known channels costs no regex per message.
        matches: dict[str, TopicMatch] = {}

        def deliver(channel: str, msg: Any) -> None:  # on the executor's loop thread
            if channel == own:
                return
            match = matches.get(channel)
            if match is None:
                m = pattern.fullmatch(channel)
                match = TopicMatch(channel, m.groupdict() if m else {})
                if len(matches) < 100_000:
                    matches[channel] = match
            if self._admit(channel, msg, match.fields.get("agent") if bound else None):
                handler(msg, match)

        sub = self.context.bus.subscribe(bus, pattern.pattern, spec.msg_type, deliver, regex=True)
        self._subs.append(sub)
        if own is not None:
            m = pattern.fullmatch(own)
            own_match = TopicMatch(own, m.groupdict() if m else {})
            own_bus = self._subscribe_bus(topic)
            if own_bus != bus:
                self._check_exposure(topic, own_bus)
            sender = self.agent if bound else None

            def deliver_own(_channel: str, msg: Any) -> None:  # on the executor's loop thread
                if self._admit(own_match.channel, msg, sender):
                    handler(msg, own_match)

            companion = self.context.bus.subscribe(own_bus, own, spec.msg_type, deliver_own)
            self._subs.append(companion)
            self._companions[sub] = companion
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        companion = self._companions.pop(sub, None)
        if companion is not None:  # subscribe_all's own-channel half goes with it
            self.unsubscribe(companion)
        self.context.bus.unsubscribe(sub)
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
        return self.context.executor.clock()

    def state_publisher(
        self, topic: str, build: Callable[[], Any], hz: float, *, periodic: bool = True, **fields: str
    ) -> Callable[[], None]:
        """Publish ``build()`` every ``1/hz`` s, and whenever the returned function is called.

        State messages go out periodically as well as on change (docs/design.md §4) so a node that starts
        late or loses a packet converges within one period. ``periodic=False``: the caller runs the
        returned function every ``1/hz`` s itself, from a timer it already has (see `ticker`).
        """

        def publish_now() -> None:
            self.publish(topic, build(), seq=None, **fields)

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

        A job whose rate divides ``hz`` (the first job's, the fastest) runs on the first job's
        timer, right after it, on the runs where its own period has come round; any other job
        gets a timer of its own. A thousand simulated agents in one process ran 50 timers a second
        each (HLC control, telemetry and state, MC tick and state) where 30 do, and a telemetry
        message built a tick after the snapshot it reports found it out of the cache.

        A shared job keeps its own due time, not a count of runs: when a loaded executor skips
        runs of the timer (it never bursts to catch up), the job still runs at its rate on the
        runs that remain, as its own timer would. Each job's exception is logged on its own.
        ``clock``: the time of each run (the run's due time unless a test gives its own).
        """
        period = 1.0 / hz
        shared: list[list[Any]] = []  # [period, due, fn]
        for rate, fn in jobs:
            every = round(hz / rate)
            if every >= 1 and abs(hz / every - rate) <= 1e-9 * rate:
                shared.append([1.0 / rate, -math.inf, fn])
            else:
                self.create_timer(1.0 / rate, fn, first_delay=self.first_delay(1.0 / rate))
        if not shared:
            return
        slack = period / 2  # a run a little early (the timer's millisecond slots) is on time
        log = self.log
        timer: Timer | None = None

        def tick() -> None:
            # The time this run of the timer was due: exact, where the loop's clock is the one
            # read when its iteration began (every slot of a backlog run in one iteration reads
            # the same, and jobs then looked early and were skipped).
            now = timer.due if clock is None else clock()  # type: ignore[union-attr]
            for job in shared:
                job_period, due, fn = job
                if now < due - slack:
                    continue
                # As the executor re-arms a timer: the next period, or a period from now if behind.
                job[1] = due + job_period if now < due + job_period else now + job_period
                try:
                    fn()
                except Exception:
                    log.exception("%s raised; the node carries on", getattr(fn, "__qualname__", fn))

        timer = self.create_timer(period, tick, first_delay=self.first_delay(period))

    def first_delay(self, period: float) -> float:
        """When a periodic timer of this agent first runs: within one ``period``, at a phase fixed
        by the agent's name, so a thousand agents started together do not all run in the same tick
        (one of 1,000 phases, so a period's runs spread over its every millisecond: 16 phases sent
        a thousand agents' datagrams in bursts that overflowed receive buffers; an agent's nodes
        share their phase). With a run seed (``Context.seed``) the phase is drawn from it as well:
        another seed starts the agents in another order, as agents switched on by hand would be."""
        seed = self.context.seed
        name = self.agent if seed is None else f"{seed}/{self.agent}"
        return period * (1.0 - (zlib.crc32(name.encode()) % _PHASES) / _PHASES)
