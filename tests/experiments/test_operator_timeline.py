"""The scripted operator's record of each agent's MC states, beside `Timeline.add` on every message
(what it did before reading the clock only for a new state)."""

from __future__ import annotations

import random

from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Context, NodeSettings, TopicMatch
from antalate_lcm.runtime.scripted_operator import ScriptedOperator, Timeline
from antalate_lcm.wire.vocabulary import McState, member_of
from tests.harness.messages import mc_state


def test_the_timelines_are_what_adding_every_message_gave() -> None:
    ctx = Context.in_process({"lan": "memq://"})
    try:
        settings = NodeSettings.from_config(
            parse_config({"agent": {"name": "op"}, "buses": {"lan": "memq://"}}), agent="operator"
        )
        op = ScriptedOperator(settings, ctx, expected_agents=3)
        clock = [100.0]
        op._now = lambda: clock[0]
        op._t0 = 100.0
        rng = random.Random(3)
        reference: dict[str, Timeline] = {}
        last = {"a": 1, "b": 1, "c": 1}
        for _ in range(2000):
            clock[0] += rng.choice([0.0, 0.05, 0.2])
            agent = rng.choice(["a", "b", "c"])
            if rng.random() < 0.1:  # a new state now and then (99: not a state, dropped)
                last[agent] = rng.choice([1, 2, 3, 4, 99])
            op._on_mc_state(mc_state(last[agent]), TopicMatch(f"{agent}/MC_STATE", {"agent": agent}))
            state = member_of(McState, last[agent])
            if state is not None:
                reference.setdefault(agent, Timeline()).add(clock[0] - 100.0, state)
        assert op.timelines == reference
        assert sum(len(t.entries) for t in reference.values()) > 20
    finally:
        ctx.close()
