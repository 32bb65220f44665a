"""A behavior that lives in its own distribution and is found only by its entry point name."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

from antalate_lcm.core.behavior import Behavior
from antalate_lcm.msgs import behavior_state_t


class Echo(Behavior):
    """Publishes ``behavior_state_t(state=params.word)`` on activation: visible proof it ran."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid")
        word: str = "echo"

    topics = {"ECHO": behavior_state_t}
    activate_on = ("MISSION",)

    def on_activate(self) -> None:
        msg = behavior_state_t()
        msg.state = self.params.word
        self.ctx.publish("ECHO", msg)
