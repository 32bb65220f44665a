"""The admission pipeline: the one place antalate signs what it sends and decides what it takes in.

docs/security.md describes the policy; this module is all of its code above
:mod:`antalate_lcm.wire.security` (the MAC, the window, the replay guard as pure functions and small
classes). A :class:`~antalate_lcm.core.context.Context` owns one :class:`Admission` (what its nodes share:
which buses the network reaches, the warnings said once per bus, where replay memory lives); every node
gets its :class:`NodeAdmission` from it (:meth:`Admission.for_node`), and so do the two places that are
not plain publish/subscribe: the OSC relaying what an operator signed (:meth:`NodeAdmission.vet_relay`,
through ``Node.relay``), and the operator console checking raw datagrams it decodes itself
(:meth:`NodeAdmission.check_datagram`). What is signed is signed by :func:`sealer`'s encoder, the nodes'
and the station client's (``antalate_lcm.station.client``, an operator's commands) alike.

A node's admission is built once and read on every message of the node's hot path:
:attr:`NodeAdmission.seal` is the encoder itself (no branch per message), :meth:`NodeAdmission.admit`
one call per consumed message.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from antalate_lcm.base.errors import InsecureBus
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.config import SecurityConfig
from antalate_lcm.core.node_settings import NodeSettings
from antalate_lcm.wire import validation
from antalate_lcm.wire.fastcodec import encode as fast_encode
from antalate_lcm.wire.security import (
    Authenticator,
    HighWaterStore,
    Rejection,
    ReplayGuard,
    SecurityPolicy,
    check_datagram,
    default_state_dir,
    network_reachable,
    signed_bytes,
)
from antalate_lcm.wire.topics import OPERATOR_INPUTS, PERSISTED_TYPES, Message, is_internal

#: s between the reminders an insecure node logs.
INSECURE_REMINDER = 60.0


def sealer(key: str) -> Callable[[Message], bytes]:
    """The encoder of a stamped message sent under ``key``: it signs (fills ``header.mac``, the one
    signing code of antalate) and returns the bytes; without a key, it only encodes. Chosen once, so
    a publish pays no branch for it."""
    return functools.partial(signed_bytes, key=key) if key else fast_encode


@dataclass(frozen=True, slots=True)
class RelayRefusal:
    """Why a relayed message was not published: ``reason`` is the counter's key (``unsigned``,
    ``retargeted``, ``invalid``, or an authenticator's :class:`~antalate_lcm.wire.security.Reason`
    value); ``logged`` when the authenticator already said it (rate-limited), so the relay need not."""

    reason: str
    text: str
    logged: bool = False


class Owner(Protocol):
    """What a node's admission reads of the node (:class:`~antalate_lcm.core.node.Node`)."""

    agent: str
    name: str
    kind: str
    settings: NodeSettings
    log: logging.Logger
    #: Read when the authenticator is first needed: a node may set its own after it was built.
    wallclock: Callable[[], float]

    def create_timer(self, period: float, fn: Callable[[], Any], *, first_delay: float | None = None) -> Any:
        """A periodic timer of the node's (an insecure node's reminders), cancelled when it stops."""
        ...


class Admission:
    """What the nodes of one context share of the pipeline (the context owns one).

    ``urls``: the context's buses (name -> URL), whose transports say whether the network reaches
    them. ``simulated``: the context runs on simulated time (no replay memory survives a run).
    """

    def __init__(self, urls: Mapping[str, str], *, simulated: bool) -> None:
        self.urls = urls
        self.simulated = simulated
        #: Buses whose missing swarm key a node of this context has already warned of: a thousand
        #: agents in one process (``antalate agent --agents 1000``) would say it a thousand times and
        #: bury every other line of the start.
        self.open_warned: set[str] = set()

    def for_node(self, node: Owner, *, watcher: bool = False) -> NodeAdmission:
        """The pipeline of one node, with the ``[security]`` section and buses of its settings.
        ``watcher``: the node watches agents rather than flying one (the operator console, the
        scripted operator), so it may read agents' state from a network bus without a swarm key."""
        return NodeAdmission(self, node, watcher)

    def state_dir(self, security: SecurityConfig, buses: Mapping[str, str]) -> Path | None:
        """Where a node keeps its replay memory: ``[security] state_dir``, else the user's state
        directory, else (every bus memq:// or file://, nothing survives the process anyway) nowhere.
        On simulated time nowhere: every run's clock starts at the same date, and a memory of the
        last run would refuse the next one's messages as replays."""
        if self.simulated:
            return None
        if security.state_dir:
            return Path(security.state_dir).expanduser()
        if any(network_reachable(url) for url in buses.values()):
            return default_state_dir()
        return None


class NodeAdmission:
    """One node's admission: signs what it publishes, admits what it consumes, applies the exposure
    policy to every input it subscribes to, vets what it relays for an operator."""

    # Slots, what every publish (`Node.outgoing`) and every admitted message reads first: a
    # thousand agents' nodes' admissions, each otherwise an object and a values array apart.
    __slots__ = (
        "_auth", "signs", "seal", "invalid", "_invalid_log",
        "admission", "node", "agent", "kind", "settings", "log", "watcher", "policy",
        "_datagram_keys", "_insecure", "_open_inputs",
    )  # fmt: skip

    def __init__(self, admission: Admission, node: Owner, watcher: bool) -> None:
        self.admission = admission
        self.node = node
        self.agent = node.agent
        self.kind = node.kind
        security = self.settings = node.settings.security
        self.log = log = node.log
        self.watcher = watcher
        self.policy = SecurityPolicy(security.swarm_key, tuple(security.previous_keys), security.window)
        #: Whether what this node publishes is signed (it has a swarm key).
        self.signs = bool(self.policy.key)
        #: The bytes of a stamped message: signed with the swarm key if there is one (`sealer`).
        self.seal = sealer(self.policy.key)
        #: Every key a signed message may carry, for the console's datagram check (empty: no check).
        self._datagram_keys = tuple(k for k in self.policy.keys if k)
        self._auth: Authenticator | None = None
        self._invalid_log = RateLimitedLog(log, period=10.0)
        #: Messages dropped by input validation (the authenticator counts its own rejections).
        self.invalid = 0
        self._insecure: dict[str, str] = {}
        self._open_inputs: dict[str, str] = {}

    # ------------------------------------------------------------------ consuming
    @property
    def authenticator(self) -> Authenticator | None:
        """The checks every consumed message passes with a swarm key (None without one)."""
        if self._auth is None and self.policy.enabled:
            store = None
            node = self.node  # its name and clock as they are now (a node may set its own clock)
            state_dir = self.admission.state_dir(self.settings, node.settings.buses)
            if state_dir is not None:
                store = HighWaterStore(state_dir / f"{self.agent}.{node.name}.replay.json")
            self._auth = Authenticator(
                self.policy,
                self.log,
                replay_guard=ReplayGuard(store, PERSISTED_TYPES),
                wallclock=node.wallclock,
            )
        return self._auth

    def admit(self, channel: str, msg: Any, expected_sender: str | None) -> bool:
        """Authenticate (with a key) and validate one consumed message; False = dropped, logged."""
        auth = self._auth
        if auth is None and self.signs:  # `authenticator`, made on the first message that needs it
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

    def needs_admission(self, msg_type: type) -> bool:
        """Whether messages of ``msg_type`` must pass :meth:`admit` (a key, or a type with an input
        check); when not, a subscription hands them straight to the handler, one call less per message."""
        return self.authenticator is not None or validation.needs_check(msg_type)

    # ------------------------------------------------------------------ the exposure policy
    def restart(self) -> None:
        """A restarted node warns (and schedules its reminder) afresh."""
        self._insecure.clear()
        self._open_inputs.clear()

    def check_exposure(self, topic: str, bus: str) -> None:
        """Refuse (raise :class:`InsecureBus`) or, with ``insecure``, loudly accept an unauthenticated
        input from the network (what a node subscribes to, before it does). The node's first insecure
        input warns at once, then every :data:`INSECURE_REMINDER` s on the node's timers."""
        url = self.admission.urls.get(bus, "")
        if self.policy.enabled or not network_reachable(url):
            return
        if topic in OPERATOR_INPUTS:
            warned = self.admission.open_warned
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
        if self.watcher or not is_internal(topic):
            return
        if not self.settings.insecure:
            raise InsecureBus(
                f"{self.kind} of {self.agent} would take {topic} from bus {bus!r} ({url}), which any host on "
                "the network can send to, with no swarm key: set [security] swarm_key (`antalate keygen`) "
                "in every config of the swarm, or run the agent's nodes in one process (`antalate agent`, "
                "internal topics then stay in memory); [security] insecure = true accepts the risk"
            )
        first = not self._insecure
        self._insecure[topic] = bus
        if first:
            self.warn_insecure()
            self.node.create_timer(INSECURE_REMINDER, self.warn_insecure, first_delay=INSECURE_REMINDER)

    def warn_insecure(self) -> None:
        where = ", ".join(f"{t} on {b!r}" for t, b in sorted(self._insecure.items()))
        self.log.warning(
            "INSECURE ([security] insecure = true, no swarm key): anyone on the network can spoof %s of %s "
            "(launch it, fly it, ground it, put it in ERROR)",
            where,
            self.agent,
        )

    # ------------------------------------------------------------------ relaying (the OSC)
    def vet_relay(self, msg: Any, *, signed: bool, channel: str) -> RelayRefusal | None:
        """Whether an operator's command that reached this agent another way (the station, through
        the OSC) may be published on ``channel``: None to publish it, else why not.

        Signed, it is published exactly as the operator signed it, so it must pass here what the
        agent's own nodes would check (its target, then MAC, window and replay, then validation): a
        compromised station can delay or drop commands but not make one up. Unsigned, it may only be
        published (as the relaying node's own message) by an agent with no swarm key, and valid.
        """
        if not signed:
            if self.policy.enabled:
                return RelayRefusal("unsigned", "the station sent it unsigned and this agent has a swarm key")
        elif msg.target and msg.target != self.agent:
            return RelayRefusal("retargeted", f"signed for {msg.target!r}, not for {self.agent!r}")
        else:
            auth = self.authenticator
            rejection = auth.check(msg, channel) if auth is not None else None
            if rejection is not None:
                return RelayRefusal(rejection.reason.value, rejection.text, logged=True)
        problem = validation.problem(msg)
        return None if problem is None else RelayRefusal("invalid", problem)

    # ------------------------------------------------------------------ raw datagrams (the console)
    @property
    def checks_datagrams(self) -> bool:
        """Whether :meth:`check_datagram` checks anything (the node has a key): what such a reader
        shows must then be checked before it is."""
        return bool(self._datagram_keys)

    def check_datagram(self, data: bytes, now: float) -> Rejection | None:
        """MAC and window of an encoded message a reader decodes itself (it keeps only some of what
        it hears: the console takes the newest state per channel), without decoding it; None
        without a key."""
        if not self._datagram_keys:
            return None
        return check_datagram(data, self._datagram_keys, self.policy.window, now)
