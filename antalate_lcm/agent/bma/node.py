"""The Behavior Module Arbiter node: follows one state topic and switches behaviors on and off.

The activation rules live in :mod:`antalate_lcm.agent.bma.arbiter` (pure); this module carries out the
arbiter's decisions, contains behavior failures and publishes ``arbiter_status_t``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import partial
from typing import Any

from antalate_lcm.agent.bma.arbiter import Arbiter
from antalate_lcm.agent.bma.plan import PEER_TOPICS, BehaviorPlan, BmaPlan, check_peer_buses, plan_bma
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.behavior import Behavior, BehaviorContext, failure_reason
from antalate_lcm.core.config import BmaConfig, Config
from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import arbiter_status_t, mc_state_t, telemetry_t
from antalate_lcm.wire.peers import PeerTable
from antalate_lcm.wire.vocabulary import McState, name_of

#: s: the longest restart back-off, and how long a behavior must run for its failures to be forgotten.
_MAX_BACKOFF = 60.0
_STREAK_RESET = 60.0
#: s between two sweeps of the peer table for agents no longer heard.
_PEER_SWEEP = 5.0


class _Slot:
    """A behavior instance with its context and the plan it came from."""

    def __init__(self, plan: BehaviorPlan) -> None:
        self.plan = plan
        self.ctx: BehaviorContext | None = None
        self.behavior: Behavior | None = None


class BmaNode(Node):
    """One ``[[bma]]`` of the config.

    Construction takes the arbiter's plan (`antalate_lcm.agent.plan.plan_agent`), or resolves it (loads
    plugins, validates params) and raises
    :class:`~antalate_lcm.base.errors.ConfigError` on a bad config; behaviors are instantiated in
    :meth:`start`, on the executor thread, where a failing constructor is contained like any other
    behavior failure.
    """

    kind = "bma"

    def __init__(self, config: Config, context: Context, bma: BmaConfig, plan: BmaPlan | None = None) -> None:
        super().__init__(NodeSettings.from_config(config), context, name=bma.name)
        self.bma = bma
        self.plan = plan if plan is not None else plan_bma(config, bma)
        self.log = logging.getLogger(f"antalate.bma.{self.agent}.{bma.name}")
        self._slots: dict[str, _Slot] = {p.name: _Slot(p) for p in self.plan.behaviors}
        self._arbiter = Arbiter({p.name: p.rule for p in self.plan.behaviors})
        self._reading_mc = self.plan.state_type is mc_state_t
        self._bad_state_log = RateLimitedLog(self.log)
        self._publish_status: Callable[[], None] = lambda: None
        #: The last status built, reused while the arbiter's `version` is the one it was built at.
        self._status_msg: arbiter_status_t | None = None
        self._status_version = -1
        #: Per behavior: failures in a row and when it last started (a restart back-off doubles per
        #: failure, and forgets them once the behavior has run for ``_STREAK_RESET`` s).
        self._streak: dict[str, int] = {}
        self._started_at: dict[str, float] = {}
        #: The swarm's latest telemetry, for the behaviors that declare ``uses_peers`` (None if none does).
        self.peers: PeerTable | None = None
        if any(p.cls.uses_peers for p in self.plan.behaviors):
            check_peer_buses(config, whole_swarm=context.whole_swarm, plans=[self.plan])
            self.peers = PeerTable(self.agent)

    # ------------------------------------------------------------------ views (executor thread or tests)
    @property
    def state(self) -> str:
        return self._arbiter.state

    def active(self) -> list[str]:
        return self._arbiter.active()

    def failures(self) -> dict[str, str]:
        return self._arbiter.failures()

    def behavior(self, name: str) -> Behavior | None:
        """The instance of behavior ``name`` (None if its constructor failed or the node is not started)."""
        return self._slots[name].behavior

    # ------------------------------------------------------------------ lifecycle
    def on_start(self) -> None:
        if self.peers is not None:
            self._listen_to_peers(self.peers)
        for name, slot in self._slots.items():
            self._construct(name, slot)
        self._publish_status = self.state_publisher(
            "ARBITER", self._status, self.bma.republish_hz, arbiter=self.bma.name
        )
        self.subscribe(self.bma.state_topic, self._on_state_msg)
        self._publish_status()
        self.log.info(
            "arbiter %s follows %s with %s",
            self.bma.name,
            self.bma.state_topic,
            ", ".join(
                f"{p.name} ({p.plugin}) on {'/'.join(sorted(p.rule.activate_on))}"
                for p in self.plan.behaviors
            )
            or "no behaviors",
        )

    def _listen_to_peers(self, table: PeerTable) -> None:
        """Feed ``table`` from every agent's TELEMETRY and MC_STATE on the swarm bus: one
        subscription per arbiter, whatever the number of behaviors reading it; this agent's own
        messages once, from the in-process bus (``Node.subscribe_all``)."""
        telemetry, state = PEER_TOPICS

        def on_telemetry(msg: telemetry_t, match: TopicMatch) -> None:
            table.update_telemetry(match.fields.get("agent") or msg.header.agent, msg, self.now)

        def on_state(msg: mc_state_t, match: TopicMatch) -> None:
            table.update_state(match.fields.get("agent") or msg.header.agent, int(msg.state), self.now)

        self.subscribe_all(telemetry, on_telemetry)
        self.subscribe_all(state, on_state)
        self.create_timer(_PEER_SWEEP, lambda: table.forget(self.now))

    def on_stop(self) -> None:
        for name in reversed(self._arbiter.active()):
            self._deactivate(name, why="arbiter stopping")
        for slot in self._slots.values():
            if slot.ctx is not None:
                slot.ctx.close()
        self._publish_status()

    def _construct(self, name: str, slot: _Slot) -> None:
        plan = slot.plan
        ctx = BehaviorContext(
            self,
            name,
            plan.params,
            plan.topics,
            state=lambda: self._arbiter.state,
            on_error=partial(self._fail, name),
            peers=self.peers if plan.cls.uses_peers else None,
        )
        slot.ctx = ctx
        try:
            slot.behavior = plan.cls(ctx)
        except Exception as exc:  # noqa: BLE001 - a broken plugin must not take the BMA down
            reason = f"{failure_reason(exc)} (in __init__)"
            self.log.error(
                "behavior %s cannot be constructed, it will never run: %s", name, reason, exc_info=True
            )
            self._arbiter.failed(name, reason, permanent=True)
            ctx.close()

    # ------------------------------------------------------------------ state
    def _on_state_msg(self, msg: Any) -> None:
        if self._reading_mc:
            state = name_of(McState, msg.state)
            if state is None:
                self._bad_state_log.log(
                    ("state", msg.state),
                    logging.WARNING,
                    "ignoring mc_state_t with undefined state value %d on %s",
                    msg.state,
                    self.bma.state_topic,
                )
                return
        else:
            state = msg.state
        if self._arbiter.settled(state):
            return  # the state republished (5 a second), nothing to decide: `apply_state` would do nothing
        self.apply_state(state)

    def apply_state(self, state: str) -> None:
        """Carry out the arbiter's decision for ``state`` (what a state message does)."""
        decision = self._arbiter.on_state(state)
        if decision.state_changed:
            self.log.info("state %s", state)
        for name in decision.unblocked:
            self.log.info(
                "%s failed earlier; it will be tried again the next time a state activates it", name
            )
        changed = False
        for name in decision.deactivate:
            self._deactivate(name, why=f"state {state}")
            changed = True
        for name in decision.activate:
            self._activate(name)
            changed = True
        for name in decision.notify:
            slot = self._slots[name]
            if slot.behavior is not None and self._arbiter.is_active(name) and slot.ctx is not None:
                slot.ctx.contain("on_state", slot.behavior.on_state, state)
        if changed or decision.state_changed:
            self._publish_status()

    # ------------------------------------------------------------------ activation
    def _activate(self, name: str) -> None:
        slot = self._slots[name]
        behavior, ctx = slot.behavior, slot.ctx
        if behavior is None or ctx is None:
            return
        ctx.begin_activation()
        # Active in the arbiter's eyes before the hook runs, so a failure inside it is handled as
        # "deactivate an active behavior" (on_deactivate attempted to release a half-done start).
        self._arbiter.activated(name)
        self._started_at[name] = self.now
        if not ctx.contain("on_activate", behavior.on_activate):
            return
        self.log.info("activated %s", name)
        if slot.plan.tick_hz > 0:
            self._start_ticking(ctx, behavior, slot.plan.tick_hz)

    def _start_ticking(self, ctx: BehaviorContext, behavior: Behavior, hz: float) -> None:
        clock = self.context.executor.clock  # `now`, bound: read on every tick
        last = clock()

        def tick() -> None:
            nonlocal last  # (a cell: no list to read from memory on every tick)
            now = clock()
            dt, last = now - last, now
            behavior.tick(dt)

        ctx.create_timer(1.0 / hz, tick, where="tick")

    def _wind_down(self, name: str) -> Exception | None:
        """Deactivate ``name`` in the arbiter's eyes, end its activation and run its
        ``on_deactivate``: what that raised, for the caller to report (the BMA carries on)."""
        slot = self._slots[name]
        self._arbiter.deactivated(name)
        if slot.ctx is not None:
            slot.ctx.end_activation()
        if slot.behavior is not None:
            try:
                slot.behavior.on_deactivate()
            except Exception as exc:  # noqa: BLE001 - reported by the caller, the BMA carries on
                return exc
        return None

    def _deactivate(self, name: str, *, why: str) -> None:
        exc = self._wind_down(name)
        if exc is not None:
            reason = f"{failure_reason(exc)} (in on_deactivate)"
            self.log.error("behavior %s raised while deactivating: %s", name, reason, exc_info=exc)
            self._arbiter.failed(name, reason)
            return
        self.log.info("deactivated %s (%s)", name, why)

    def _fail(self, name: str, where: str, exc: BaseException) -> None:
        """A hook, handler or timer of ``name`` raised: deactivate it, report it, restart it after a
        back-off if the state still wants it (docs/behaviors.md), carry on."""
        slot = self._slots[name]
        reason = f"{failure_reason(exc)} (in {where})"
        if self.now - self._started_at.get(name, self.now) >= _STREAK_RESET:
            self._streak[name] = 0
        streak = self._streak[name] = self._streak.get(name, 0) + 1
        self.log.error(
            "behavior %s failed and is deactivated (failure %d in a row): %s",
            name,
            streak,
            reason,
            exc_info=exc,
        )
        if self._arbiter.is_active(name):
            also = self._wind_down(name)
            if also is not None:  # already failing: the first reason is the one reported
                self.log.warning("%s: on_deactivate after the failure raised too", name, exc_info=also)
        self._arbiter.failed(name, reason)
        self._publish_status()
        backoff = self.bma.restart_backoff
        if backoff > 0 and self._arbiter.state in slot.plan.rule.activate_on:
            delay = min(backoff * 2 ** (streak - 1), _MAX_BACKOFF)
            self.log.warning("%s will be restarted in %g s if the state still activates it", name, delay)
            self.call_later(delay, lambda: self._retry(name))

    def _retry(self, name: str) -> None:
        if self.started and self._arbiter.retry(name):
            self.log.info("restarting %s after its failure", name)
            self.apply_state(self._arbiter.state)

    # ------------------------------------------------------------------ status
    def _status(self) -> arbiter_status_t:
        arbiter = self._arbiter
        if arbiter.version == self._status_version and self._status_msg is not None:
            # Unchanged since it was built: the periodic republication sends it again (publish
            # stamps a fresh header). Not with an experiment's interference, which may hold on to it.
            return self._status_msg
        msg = arbiter_status_t()
        msg.arbiter = self.bma.name
        msg.state = self._arbiter.state
        msg.active = self._arbiter.active()
        msg.n = len(msg.active)
        msg.failed = [f"{name}: {reason}" for name, reason in self._arbiter.failures().items()]
        msg.n_failed = len(msg.failed)
        if self.interference is None:
            self._status_msg, self._status_version = msg, arbiter.version
        return msg
