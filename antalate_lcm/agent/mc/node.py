"""The Mission Control node: wires `MissionControl` to the bus.

Hears operator commands on its own channel and the broadcast ``SWARM/OPERATOR_CMD``, and the HLC
state; publishes ``mc_state_t`` on every change and periodically. Every transition and every rejected
command is logged with its reason.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from antalate_lcm.agent.mc.machine import McOutcome, McParams, MissionControl
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, Node, NodeSettings, shared_params
from antalate_lcm.msgs import hlc_state_t, mc_state_t, operator_cmd_t
from antalate_lcm.wire.vocabulary import Command, McState, name_of

_TICK_PERIOD = 0.1  # s: resolution of the takeoff-acknowledgement timeout and the HLC watchdog


class McNode(Node):
    kind = "mc"
    # Its own attributes in slots, as the HLC node's: read on every tick (the base keeps a __dict__).
    __slots__ = ("machine", "_publish_state", "_reject_log", "_clock")

    def __init__(self, config: Config, context: Context) -> None:
        super().__init__(NodeSettings.from_config(config), context)
        #: The agent's whole config, for this node's own logic (the base node reads only its settings).
        self.config = config
        m = config.mc
        self.machine = MissionControl(
            shared_params(McParams, m, "takeoff_ack_timeout", "hlc_timeout", "on_link_regained")
        )
        self._publish_state: Callable[[], None] = lambda: None
        #: Rejected commands are logged once per (command, state) per period: well-formed junk
        #: repeated at line rate must not drown the log.
        self._reject_log = RateLimitedLog(self.log, period=10.0)
        self._clock = context.executor.clock  # `now`, without the property (the 10 Hz tick reads it)

    def on_start(self) -> None:
        self.subscribe("OPERATOR_CMD", self._on_command)
        self.subscribe("SWARM_OPERATOR_CMD", self._on_command)
        self.subscribe("HLC_STATE", self._on_hlc_state)
        hz = self.config.mc.republish_hz
        self._publish_state = self.state_publisher("MC_STATE", self._state_msg, hz, periodic=False)
        # One timer when the rates allow (10 Hz tick, 5 Hz state by default).
        self.ticker(1.0 / _TICK_PERIOD, [(1.0 / _TICK_PERIOD, self._tick), (hz, self._publish_state)])
        self._publish_state()
        self.log.info("MC started in %s", self.machine.state.name)

    @property
    def state(self) -> McState:
        return self.machine.state

    def _state_msg(self) -> mc_state_t:
        # The context's one mc_state_t, refilled (every field) at every publish: 5 a second and on
        # every change; publish stamps its header and encodes it at once (Node.outgoing).
        msg = self.outgoing(mc_state_t)
        machine = self.machine
        msg.state = int(machine.state)
        msg.last_command_seq = machine.last_command_seq
        msg.takeoff_altitude = float(machine.takeoff_altitude)
        msg.reason = machine.reason
        return msg

    # ------------------------------------------------------------------ inputs
    def _on_command(self, cmd: operator_cmd_t) -> None:
        if cmd.target and cmd.target != self.agent:
            return
        # Authenticated (swarm key: MAC, window, per-sender replay guard persisted across restarts)
        # and validated (altitude) by Node.subscribe before it gets here: docs/security.md.
        sender = cmd.header.agent
        name = name_of(Command, cmd.command) or f"#{cmd.command}"
        outcome = self.machine.on_command(
            cmd.command, cmd.header.seq, self.now, altitude=_finite_or_zero(cmd.altitude), sender=sender
        )
        self._report(outcome, f"operator {name} (seq {cmd.header.seq} from {sender or '?'})")

    def _on_hlc_state(self, msg: hlc_state_t) -> None:
        outcome = self.machine.on_hlc_state(msg.state, self._clock())
        if outcome.transition is not None or not outcome.accepted or outcome.duplicate:
            self._report(outcome, "HLC state")

    def _tick(self) -> None:
        # 10 times a second per agent, and nearly always an outcome _report does nothing with.
        outcome = self.machine.tick(self._clock())
        if outcome.transition is not None or not outcome.accepted or outcome.duplicate:
            self._report(outcome, "timer")

    # ------------------------------------------------------------------ outputs
    def _report(self, outcome: McOutcome, what: str) -> None:
        if outcome.transition is not None:
            t = outcome.transition
            level = logging.INFO
            if t.to_state in (McState.ERROR, McState.HLC_LOST):
                level = logging.ERROR
            elif t.from_state in (McState.ERROR, McState.HLC_LOST) or t.to_state is McState.HOLD:
                level = logging.WARNING  # recovered, or stopped by a failsafe: the operator must look
            self.log.log(level, "%s -> %s on %s: %s", t.from_state.name, t.to_state.name, what, t.reason)
            self._publish_state()
        elif not outcome.accepted:
            self._reject_log.log(
                ("rejected", what.split(" (", 1)[0], self.machine.state),
                logging.WARNING,
                "rejected %s in %s: %s",
                what,
                self.machine.state.name,
                outcome.reason,
            )
            self._publish_state()  # the operator sees at once that it was not acknowledged
        elif outcome.duplicate:
            self.log.debug("duplicate %s ignored", what)
            self._publish_state()  # re-acknowledge: the first ack may have been lost


def _finite_or_zero(x: Any) -> float:
    try:
        value = float(x)
    except (TypeError, ValueError):
        return 0.0
    return value if value == value and abs(value) != float("inf") and value >= 0 else 0.0
