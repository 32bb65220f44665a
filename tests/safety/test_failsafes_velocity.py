"""No behavior set-point reaches the autopilot over a stale link, in LLC_DOWN or in HOLD (issue 12).

The guard's rule on its own, then a whole in-process agent (real MC and HLC nodes, the real sim) whose
autopilot link is cut while a behavior streams velocity commands, comes back, and holds.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.agent.hlc.velocity_guard import (
    VelocityCommand,
    VelocityGuard,
    VelocityLimits,
    Verdict,
    check_velocity,
)
from antalate_lcm.agent.mc.node import McNode
from antalate_lcm.core.config import AgentConfig, Config, HlcConfig, McConfig
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import operator_cmd_t, velocity_cmd_t
from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.sim import SimAdapter
from antalate_lcm.wire.vocabulary import HlcState, McState
from tests.harness.polling import wait_for

LIMITS = VelocityLimits(velocity_timeout=0.5, max_link_age=1.5)  # the node passes its link_timeout
A, M = HlcState.AIRBORNE, McState.MISSION


def cmd(at: float, vx: float = 1.0) -> VelocityCommand:
    return VelocityCommand(vx, 0.0, 0.0, 0.0, Frame.NED, at)


def test_stale_link_withholds_every_command() -> None:
    assert check_velocity(cmd(10.0), 10.0, A, M, LIMITS, link_age=1.49).verdict is Verdict.SEND
    for age in (1.5, 10.0, math.inf, math.nan):
        decision = check_velocity(cmd(10.0), 10.0, A, M, LIMITS, link_age=age)
        assert decision.verdict is Verdict.REJECT and decision.send is None
        assert "link" in decision.reason


def test_hover_owed_on_a_stale_link_waits_until_the_link_is_fresh() -> None:
    guard = VelocityGuard(LIMITS)
    assert guard.on_command(cmd(10.0), 10.0, A, M, link_age=0.1).verdict is Verdict.SEND
    assert guard.tick(11.0, A, M, link_age=2.0) is None  # nothing can reach the vehicle now
    hover = guard.tick(11.1, A, M, link_age=0.1)
    assert hover is not None and hover.verdict is Verdict.HOVER
    assert guard.tick(11.2, A, M, link_age=0.1) is None  # once


def test_nothing_passes_in_llc_down_or_hold() -> None:
    for state in (HlcState.LLC_DOWN, HlcState.HOLD):
        for mc in McState:
            assert check_velocity(cmd(10.0), 10.0, state, mc, LIMITS).verdict is Verdict.REJECT


class RecordingSim(SimAdapter):
    """The real sim, remembering every set-point it was handed and in what circumstances."""

    def __init__(self, params: dict[str, Any], clock: Any) -> None:
        super().__init__(params, clock=clock)
        self.node: HlcNode | None = None
        self.calls: list[tuple[float, float, HlcState]] = []  # (vx, link age at the call, HLC state)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        lost_at = self._link_lost_at
        age = 0.0 if lost_at is None else self.clock() - lost_at
        assert self.node is not None
        self.calls.append((vx, age, self.node.state))
        super().set_velocity(vx, vy, vz, yaw_rate, frame)


def test_an_agent_sends_no_setpoint_over_a_stale_link_in_llc_down_or_in_hold() -> None:
    config = Config(
        agent=AgentConfig(name="streamer"),
        buses={"lan": "memq://"},
        mc=McConfig(on_link_regained="hold"),
        hlc=HlcConfig(default_takeoff_altitude=2.0, link_timeout=1.0, autopilot_params={"climb_rate": 5.0}),
    )
    context = Context.in_process(config.buses)
    sim = RecordingSim({"climb_rate": 5.0}, clock=context.executor.clock)
    hlc = HlcNode(config, context, adapter=sim)
    sim.node = hlc
    mc = McNode(config, context)
    behavior = Node(NodeSettings.from_config(config), context, name="behavior")
    streaming = threading.Event()
    done = threading.Event()

    def stream() -> None:
        while not done.is_set():
            if streaming.is_set():
                v = velocity_cmd_t()
                v.frame, v.vx = velocity_cmd_t.NED, 2.0
                behavior.publish("VELOCITY_CMD", v)
            time.sleep(0.05)

    streamer = threading.Thread(target=stream)
    context.buses.open()
    context.executor.start()
    try:
        hlc.start()
        mc.start()
        streamer.start()
        assert wait_for(lambda: mc.state is McState.STANDBY, 10)
        takeoff = operator_cmd_t()
        takeoff.command = operator_cmd_t.TAKEOFF
        Node(NodeSettings.from_config(config), context, name="operator").publish("OPERATOR_CMD", takeoff)
        assert wait_for(lambda: mc.state is McState.MISSION, 10)
        streaming.set()
        assert wait_for(lambda: any(vx == 2.0 for vx, _, _ in sim.calls), 5)  # mission flight: passes
        context.executor.run_sync(lambda: sim.set_link_loss(True))
        assert wait_for(lambda: hlc.state is HlcState.LLC_DOWN, 10)
        time.sleep(1.0)  # the behavior keeps streaming into LLC_DOWN
        context.executor.run_sync(lambda: sim.set_link_loss(False))
        assert wait_for(lambda: hlc.state is HlcState.HOLD and mc.state is McState.HOLD, 10)
        time.sleep(1.0)  # and into HOLD
        assert hlc.state is HlcState.HOLD and sim.state().in_air
    finally:
        done.set()
        streaming.clear()
        if streamer.is_alive():
            streamer.join(5)
        mc.stop()
        hlc.stop()
        context.close()
    behavior_calls = [(vx, age, state) for vx, age, state in sim.calls if vx != 0.0]
    assert behavior_calls, "the behavior's set-points never passed in mission flight"
    too_old = [c for c in behavior_calls if c[1] >= config.hlc.link_timeout]
    assert too_old == [], too_old
    assert {state for _, _, state in behavior_calls} == {HlcState.AIRBORNE}
    in_hold = [c for c in sim.calls if c[2] is HlcState.HOLD]
    assert [vx for vx, _, _ in in_hold] == [0.0]  # only the HLC's own hover on entering HOLD
    assert not [c for c in sim.calls if c[2] is HlcState.LLC_DOWN]
