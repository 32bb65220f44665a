"""Helpers for the BMA and behavior tests: an in-memory harness and the behaviors tests load by name.

The behaviors here are loaded by ``module:Class`` (``tests.harness.bma:Recorder``), which also
exercises that way of naming a plugin; `FlyAt` is the adversary of the safety filter's end-to-end
tests (tests/safety/test_safety_e2e.py, tests/sitl_arducopter/test_safety.py), loaded by the agent
processes they start.
"""

from __future__ import annotations

import math
import time
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.agent.bma import BmaNode
from antalate_lcm.base.geo import local_ne
from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.node import Node, NodeSettings
from antalate_lcm.msgs import behavior_state_t, mc_state_t, telemetry_t, velocity_cmd_t
from tests.harness.inprocess import InProcess

AGENT = "a1"


def make_config(bma: list[dict[str, Any]], **extra: Any) -> Config:
    """A config on one memq:// bus (every node of the test in this process)."""
    data: dict[str, Any] = {"agent": {"name": AGENT}, "buses": {"lan": "memq://"}, "bma": bma, **extra}
    return parse_config(data, "test.toml")


class Harness(InProcess):
    """A started executor and bus, a probe node for the test's own traffic, and BMAs to run."""

    def __init__(self, config: Config) -> None:
        super().__init__(config)
        self.probe = self.add(Node(NodeSettings.from_config(config), self.context, name="probe"))

    def bma(self, name: str) -> BmaNode:
        spec = next(b for b in self.config.bma if b.name == name)
        return self.add(BmaNode(self.config, self.context, spec))

    def mc_state(self, state: str) -> None:
        msg = mc_state_t()
        msg.state = getattr(mc_state_t, state)
        self.probe.publish("MC_STATE", msg)

    def behavior_state(self, topic: str, state: str) -> None:
        msg = behavior_state_t()
        msg.state = state
        self.probe.publish(topic, msg)

    def record(self, topic: str, **fields: str) -> list[Any]:
        """Every message the probe receives on ``topic`` from now on (appended on the executor thread)."""
        got: list[Any] = []
        self.probe.subscribe(topic, got.append, **fields)
        return got

    def settle(self) -> None:
        """Let queued deliveries run: memq delivers on the dispatcher thread, then the executor."""
        time.sleep(0.05)
        self.sync(lambda: None)


def harness(config: Config) -> Harness:
    """``with harness(config) as h``: closed at the end of the block."""
    return Harness(config)


# ---------------------------------------------------------------------- test behaviors
class Recorder(Behavior):
    """Logs its lifecycle into ``events`` (a class-level list shared by all instances, for the tests)."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid")
        label: str = ""
        speed: float = Field(default=1.0, gt=0)

    events: list[tuple[str, str]] = []

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.ticks: list[float] = []
        self.states: list[str] = []

    def on_activate(self) -> None:
        Recorder.events.append((self.ctx.name, "activate"))

    def on_deactivate(self) -> None:
        Recorder.events.append((self.ctx.name, "deactivate"))

    def on_state(self, state: str) -> None:
        self.states.append(state)

    def tick(self, dt: float) -> None:
        self.ticks.append(dt)


class Raiser(Behavior):
    """Raises where told: ``where`` ∈ on_activate, tick, handler, on_deactivate, init, on_state."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid")
        where: str
        #: For ``handler``: the topic whose messages make it raise.
        topic: str = "TELEMETRY"

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        if self.params.where == "init":
            raise RuntimeError("broken constructor")
        self.deactivations = 0

    def on_activate(self) -> None:
        if self.params.where == "on_activate":
            raise ValueError("cannot start")
        if self.params.where == "handler":
            self.ctx.subscribe(self.params.topic, self._boom)

    def _boom(self, msg: Any) -> None:
        raise KeyError("bad message")

    def tick(self, dt: float) -> None:
        if self.params.where == "tick":
            raise ZeroDivisionError("tick blew up")

    def on_state(self, state: str) -> None:
        if self.params.where == "on_state":
            raise RuntimeError(f"cannot handle {state}")

    def on_deactivate(self) -> None:
        self.deactivations += 1
        if self.params.where == "on_deactivate":
            raise OSError("cannot stop")


class ModeSwitcher(Behavior):
    """Cascading: publishes a ``behavior_state_t`` on its MODE topic (remapped in the config)."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid")
        first: str = "SEARCH"
        then: str = "FOLLOW"
        after: float = Field(default=0.2, gt=0)

    topics = {"MODE": behavior_state_t}
    tick_hz = 20.0

    def on_activate(self) -> None:
        self.mode = self.params.first
        self._since = self.ctx.now
        self._send()

    def tick(self, dt: float) -> None:
        if self.mode == self.params.first and self.ctx.now - self._since >= self.params.after:
            self.mode = self.params.then
        self._send()

    def on_deactivate(self) -> None:
        self.mode = "IDLE"
        self._send()

    def _send(self) -> None:
        msg = behavior_state_t()
        msg.state = self.mode
        self.ctx.publish("MODE", msg)


class Delayed(Behavior):
    """Schedules a one-shot on activation: shows scoped timers die with the activation."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid")
        delay: float = 0.2

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.fired = 0

    def on_activate(self) -> None:
        self.ctx.call_later(self.params.delay, self._fire)

    def _fire(self) -> None:
        self.fired += 1


# ------------------------------------------------- behaviors that try to crash the swarm
class FlyAt(Behavior):
    """Full speed at (lat, lon) whatever is in the way (the swarm's centroid, a partner's start for a
    head-on pair, a point outside the fence) until deactivated; it never slows down, it passes the point
    and comes back."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

        lat: float
        lon: float
        speed: float = 5.0

    params: Params
    topics = {"TELEMETRY": telemetry_t, "VELOCITY_CMD": velocity_cmd_t}
    activate_on = ("MISSION",)
    tick_hz = 10.0

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.here: tuple[float, float] | None = None
        ctx.subscribe("TELEMETRY", self._on_telemetry)

    def _on_telemetry(self, msg: telemetry_t) -> None:
        if math.isfinite(msg.lat) and math.isfinite(msg.lon):
            self.here = (msg.lat, msg.lon)

    def on_activate(self) -> None:
        self.tick(0.0)

    def tick(self, dt: float) -> None:
        if self.here is None:
            return
        north, east = local_ne(self.here[0], self.here[1], self.params.lat, self.params.lon)
        d = math.hypot(north, east)
        msg = velocity_cmd_t()
        msg.frame = velocity_cmd_t.NED
        s = self.params.speed / d if d > 0.05 else 0.0
        msg.vx, msg.vy, msg.vz, msg.yaw_rate = north * s, east * s, 0.0, 0.0
        self.ctx.publish("VELOCITY_CMD", msg)
