"""The paper's minimal operator (its Figure 4): an agent that flies with no human at all.

It commands TAKEOFF whenever Mission Control is in STANDBY and, optionally, RTL after a set time in
MISSION. Because the MC only acknowledges a command by changing state, the TAKEOFF is resent every
``retry`` seconds while the MC stays in STANDBY (a lost datagram or a refused arming is retried),
and the RTL likewise while it stays in MISSION. Leaving STANDBY/MISSION deactivates the behavior,
which is what stops the resending.

Default activation: ``activate_on = ["STANDBY", "MISSION"]`` on an ``MC_STATE`` arbiter.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.msgs import operator_cmd_t

_COMMAND_NAMES = {operator_cmd_t.TAKEOFF: "TAKEOFF", operator_cmd_t.RTL: "RTL", operator_cmd_t.LAND: "LAND"}


class AutoOperator(Behavior):
    """TAKEOFF in STANDBY; RTL after ``rtl_after`` s of MISSION; ``max_flights`` to stop re-flying."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

        #: Seconds in MISSION before commanding RTL; unset = never (the mission runs until a human
        #: or the battery ends it).
        rtl_after: float | None = Field(default=None, gt=0, allow_inf_nan=False)
        #: Takeoff altitude in metres; 0 = the HLC's configured default.
        altitude: float = Field(default=0.0, ge=0, allow_inf_nan=False)
        #: Seconds between resends of a command the MC has not acted on yet.
        retry: float = Field(default=2.0, gt=0, allow_inf_nan=False)
        #: Take off at most this many times (counted on entering MISSION); 0 = every time the MC is
        #: STANDBY, as in the paper. With ``rtl_after``, 1 gives a single autonomous sortie.
        max_flights: int = Field(default=0, ge=0)

    params: Params
    topics = {"OPERATOR_CMD": operator_cmd_t}
    activate_on = ("STANDBY", "MISSION")
    tick_hz = 5.0

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        #: Instance state survives deactivation: the flight count spans the whole run.
        self.flights = 0
        self._mission_start: float | None = None
        self._next_send = 0.0

    def on_activate(self) -> None:
        self._enter(self.ctx.state)

    def on_state(self, state: str) -> None:
        self._enter(state)

    def on_deactivate(self) -> None:
        self._mission_start = None

    def _enter(self, state: str) -> None:
        now = self.ctx.now
        self._next_send = now  # a new state acts at once, then every `retry` s
        if state == "MISSION":
            self.flights += 1
            self._mission_start = now
            if self.params.rtl_after is not None:
                self.log.info("flight %d: RTL in %g s", self.flights, self.params.rtl_after)
        else:
            self._mission_start = None
        self.tick(0.0)

    def tick(self, dt: float) -> None:
        now = self.ctx.now
        state = self.ctx.state
        if now < self._next_send:
            return
        if state == "STANDBY":
            if self.params.max_flights and self.flights >= self.params.max_flights:
                return
            self._send(operator_cmd_t.TAKEOFF)
        elif state == "MISSION" and self.params.rtl_after is not None and self._mission_start is not None:
            if now - self._mission_start < self.params.rtl_after:
                return
            self._send(operator_cmd_t.RTL)
        else:
            return
        self._next_send = now + self.params.retry

    def _send(self, command: int) -> None:
        msg = operator_cmd_t()
        msg.command = command
        msg.target = self.ctx.agent
        msg.altitude = float(self.params.altitude) if command == operator_cmd_t.TAKEOFF else 0.0
        self.ctx.publish("OPERATOR_CMD", msg)
        self.log.info("sent %s (seq %d)", _COMMAND_NAMES[command], msg.header.seq)
