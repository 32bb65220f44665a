"""The behavior contract (docs/design.md §8): what a plugin implements and what it is given.

A behavior is a small class the Behavior Module Arbiter (BMA) switches on and off by state. It never
sees LCM, channels or threads: it names topics (``"VELOCITY_CMD"``), the config decides where they
travel, and every hook runs on the process's single executor thread, so behavior code needs no locks.

Failure semantics are the BMA's promise to the rest of the agent: an exception escaping any hook,
handler or timer of a behavior deactivates that behavior and reports it in ``arbiter_status_t``;
the BMA and its other behaviors carry on. See ``docs/behaviors.md``.
"""

from __future__ import annotations

import logging
import zlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel, ConfigDict

from antalate_lcm.base.errors import BehaviorError as BehaviorError
from antalate_lcm.core.bus import Subscription
from antalate_lcm.core.executor import Timer
from antalate_lcm.wire.peers import PeerTable
from antalate_lcm.wire.topics import Message

if TYPE_CHECKING:
    from antalate_lcm.core.node import Node, Publisher


class NoParams(BaseModel):
    """The default ``Params``: no parameters, and any given is a config error (typos fail at load)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Behavior(ABC):
    """Base class of every behavior plugin.

    Subclasses declare, as class attributes:

    - ``Params``: a pydantic model of the ``params`` table. It is validated when the config is
      loaded, strictly (`antalate_lcm.base.strict`: "5" is not a number), so a bad value stops the
      program before any node starts, naming the key.
    - ``topics``: the topic names the behavior uses, each with the message type it expects (or
      ``None`` for any). A config may remap them (``topics = {MODE = "SWARM_MODE"}``); the remap and
      the types are checked at load.
    - ``activate_on`` / ``deactivate_on``: default states, used when the config gives none.
    - ``tick_hz``: default rate of :meth:`tick` (0 = never ticked), overridden by the config's ``tick_hz``.
    - ``uses_peers``: True for a behavior that reads ``ctx.peers`` (every other agent's latest
      telemetry). Its BMA then listens to the swarm's TELEMETRY and MC_STATE, and a config in which
      those cannot reach it (a process-local bus while agents run in several processes) fails at
      start instead of splitting the swarm silently.

    Lifecycle: constructed once when the BMA starts (keep ``__init__`` cheap and free of I/O; the
    instance, and so its attributes, lives across activations) → :meth:`on_activate` /
    :meth:`on_deactivate` as the state changes, :meth:`tick` while active, :meth:`on_state` when the
    state changes but the behavior stays active.
    """

    Params: ClassVar[type[BaseModel]] = NoParams
    topics: ClassVar[Mapping[str, type | None]] = {}
    activate_on: ClassVar[tuple[str, ...]] = ()
    deactivate_on: ClassVar[tuple[str, ...]] = ()
    tick_hz: ClassVar[float] = 0.0
    uses_peers: ClassVar[bool] = False

    def __init__(self, ctx: BehaviorContext) -> None:
        self.ctx = ctx
        self.params: Any = ctx.params
        self.log = ctx.log

    @abstractmethod
    def on_activate(self) -> None:
        """Start: subscribe, spawn, publish. Subscriptions and timers made here end on deactivation."""

    def on_deactivate(self) -> None:  # noqa: B027 - optional hook, deliberately a no-op
        """Stop what ``on_activate`` started beyond subscriptions and timers (those go automatically).

        Also called after ``on_activate`` raised, so it must cope with a half-done activation.
        """

    def on_state(self, state: str) -> None:  # noqa: B027 - optional hook
        """The arbiter's state changed to ``state`` and this behavior stays active in it."""

    def tick(self, dt: float) -> None:  # noqa: B027 - optional hook
        """Called at the configured rate while active; ``dt`` = seconds since the previous tick
        (or since activation, for the first)."""


class BehaviorContext:
    """What a behavior may touch: its topics, params, logger, clock and the arbiter's state.

    Built by the BMA; every callback handed to it is wrapped so that an exception is reported
    through ``on_error`` (which deactivates and marks the behavior failed) instead of reaching the
    executor.
    """

    def __init__(
        self,
        node: Node,
        name: str,
        params: BaseModel,
        topics: Mapping[str, str],
        *,
        state: Callable[[], str],
        on_error: Callable[[str, BaseException], None],
        peers: PeerTable | None = None,
    ) -> None:
        self._node = node
        #: The executor's clock, bound once: `now` is read on every tick and many a message.
        self._clock: Callable[[], float] = node.context.executor.clock
        self._peers = peers
        self._topics = dict(topics)
        #: The behavior's topic (published without template fields) -> its node's publisher and the
        #: type it carries: a behavior's commands (10-20 a second) look neither up again.
        self._publishers: dict[str, tuple[Publisher, type]] = {}
        #: The topic last published without fields (the same string object), its publisher and type:
        #: a behavior's 10 Hz command reads them here, with the context's other attributes, not from
        #: a dict and its entry out of the cache (a thousand agents' behaviors).
        self._last_topic: str | None = None
        self._last_pub: Publisher | None = None
        self._last_type: type = object
        self._state = state
        self._on_error = on_error
        self.name = name
        self.params = params
        self.agent: str = node.agent
        self.log = logging.getLogger(f"antalate.behavior.{node.agent}.{name}")
        #: Bumped on every activation and deactivation: a callback from an earlier activation that
        #: was already queued on the executor when its subscription was dropped is discarded.
        self._generation = 0
        self._active = False
        self._closed = False
        self._scoped_subs: list[Subscription] = []
        self._scoped_timers: list[Timer] = []
        self._persistent_subs: list[Subscription] = []
        self._persistent_timers: list[Timer] = []

    # ------------------------------------------------------------------ facts
    @property
    def seed(self) -> int | None:
        """A seed for this behavior's random draws, derived from the run's (``antalate run --seed``,
        and always on simulated time), this agent and this behavior: seed a ``random.Random`` with
        it and the run stays a function of its seed. None when the run has none."""
        run_seed = self._node.context.seed
        if run_seed is None:
            return None
        return zlib.crc32(f"{run_seed}/{self.agent}/{self.name}".encode())

    @property
    def now(self) -> float:
        """Monotonic seconds on the executor's clock; use it for every timeout and rate."""
        return self._clock()

    @property
    def state(self) -> str:
        """The state the arbiter last received (e.g. ``"MISSION"``, or a cascaded state)."""
        return self._state()

    @property
    def active(self) -> bool:
        return self._active

    @property
    def peers(self) -> PeerTable:
        """Every other agent's latest position, velocity, heading and MC state (docs/behaviors.md,
        "Peers"), fed by the BMA from the swarm's own telemetry; ``peers.me`` is this agent.

        Only for a behavior that declares ``uses_peers = True``: that is what makes its BMA listen
        and check at start that the peers can be heard.
        """
        if self._peers is None:
            raise BehaviorError(
                f"behavior {self.name} reads ctx.peers but its class does not declare uses_peers = True"
            )
        return self._peers

    def topic(self, name: str) -> str:
        """The config topic that the behavior's topic ``name`` is bound to (after remaps)."""
        return self._topics.get(name, name)

    # ------------------------------------------------------------------ messaging
    def publish(self, topic: str, msg: Message, **fields: str) -> bool:
        """Publish on the behavior's ``topic``; the header is stamped (and, with a swarm key, the
        message signed) by the node, so a behavior acting as an operator works under authentication."""
        pub = self._last_pub
        if topic is self._last_topic and pub is not None and not fields:
            expected = self._last_type
        else:
            entry = None if fields else self._publishers.get(topic)
            if entry is None:
                mapped = self.topic(topic)
                entry = (self._node.publisher(mapped, **fields), self._node.topic_spec(mapped).msg_type)
                if not fields:
                    self._publishers[topic] = entry
            pub, expected = entry
            if not fields:
                self._last_topic, self._last_pub, self._last_type = topic, pub, expected
        if not isinstance(msg, expected):
            raise TypeError(f"topic {pub.topic!r} carries {expected.__name__}, not {type(msg).__name__}")
        return pub.publish(msg)

    def subscribe(self, topic: str, handler: Callable[[Any], None], **fields: str) -> Subscription:
        """Deliver this agent's ``topic`` to ``handler`` on the executor thread.

        Made while active (normally in ``on_activate``): dropped automatically on deactivation.
        Made while inactive (in ``__init__``): kept for the life of the BMA, handler called even
        while the behavior is inactive (e.g. to remember the latest telemetry).
        """
        scoped = self._active
        gen = self._generation
        where = f"handler for {topic}"
        on_error = self._on_error

        def deliver(msg: Any) -> None:
            if self._closed or (scoped and gen != self._generation):
                return
            try:  # `contain`, inline: every message a behavior hears passes here
                handler(msg)
            except Exception as exc:  # noqa: BLE001 - a plugin's failure is contained
                on_error(where, exc)

        sub = self._node.subscribe(self.topic(topic), deliver, **fields)
        (self._scoped_subs if scoped else self._persistent_subs).append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        self._node.unsubscribe(sub)
        for subs in (self._scoped_subs, self._persistent_subs):
            if sub in subs:
                subs.remove(sub)

    def verify(self, msg: Any) -> str | None:
        """Kept for plugins written before the node authenticated every input: always None.

        Every message a handler receives has already passed the node's checks (MAC, replay window,
        replay guard, input validation: docs/security.md); a rejected one never reaches the handler.
        """
        return None

    # ------------------------------------------------------------------ time
    def call_later(self, delay: float, fn: Callable[[], Any]) -> Timer:
        """Run ``fn`` once after ``delay`` s (cancelled on deactivation if made while active)."""
        executor = self._node.context.executor
        return self._timer(fn, lambda f: executor.call_later(delay, f), f"timer {_name(fn)}", oneshot=True)

    def create_timer(self, period: float, fn: Callable[[], Any], *, where: str | None = None) -> Timer:
        """Run ``fn`` every ``period`` s (cancelled on deactivation if made while active).

        ``where`` names it in the failure reason if ``fn`` raises (default ``timer <fn's name>``).
        """
        executor = self._node.context.executor
        return self._timer(fn, lambda f: executor.create_timer(period, f), where or f"timer {_name(fn)}")

    def _timer(
        self,
        fn: Callable[[], Any],
        make: Callable[[Callable[[], None]], Timer],
        where: str,
        *,
        oneshot: bool = False,
    ) -> Timer:
        # Timers are kept here, not in the node's list, so the many one-shots a behavior may make
        # over a long flight are forgotten once they have run.
        scoped = self._active
        gen = self._generation
        owner = self._scoped_timers if scoped else self._persistent_timers
        on_error = self._on_error

        def run() -> None:
            if oneshot and timer in owner:
                owner.remove(timer)
            if self._closed or (scoped and gen != self._generation):
                return
            try:  # `contain`, inline: a behavior's tick (10 a second) passes here
                fn()
            except Exception as exc:  # noqa: BLE001 - a plugin's failure is contained
                on_error(where, exc)

        timer = make(run)
        owner.append(timer)
        return timer

    # ------------------------------------------------------------------ used by the BMA
    def contain(self, where: str, fn: Callable[..., Any], *args: Any) -> bool:
        """Call ``fn``; on an exception report it (the behavior fails) and return False.

        Not a "guard": that word is taken by the transition tables' row conditions, the replay guard
        and the velocity guard.
        """
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - the whole point: contain a plugin's failure
            self._on_error(where, exc)
            return False
        return True

    def begin_activation(self) -> None:
        """The BMA activates the behavior: what it subscribes to or times from now on is scoped."""
        self._generation += 1
        self._active = True

    def end_activation(self) -> None:
        """The BMA deactivates the behavior: drop what the activation acquired; safe to call twice."""
        self._generation += 1
        self._active = False
        self._release(self._scoped_timers, self._scoped_subs)

    def close(self) -> None:
        """The BMA drops the behavior for good (stop, or a failed construction): release everything."""
        self.end_activation()
        self._closed = True
        self._release(self._persistent_timers, self._persistent_subs)

    def _release(self, timers: list[Timer], subs: list[Subscription]) -> None:
        """Cancel and drop what one scope (an activation, or the behavior's whole life) acquired."""
        for timer in timers:
            timer.cancel()
        for sub in subs:
            self._node.unsubscribe(sub)
        timers.clear()
        subs.clear()


def _name(fn: Callable[..., Any]) -> str:
    return getattr(fn, "__name__", None) or type(fn).__name__


def failure_reason(exc: BaseException) -> str:
    """One line for ``arbiter_status_t.failed``: the message of a :class:`BehaviorError`, else type and message."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, BehaviorError):
        return text or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


__all__ = ["Behavior", "BehaviorContext", "BehaviorError", "NoParams", "failure_reason"]
