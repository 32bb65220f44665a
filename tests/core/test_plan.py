"""One plugin-loading path (antalate_lcm/agent/plan.py): the plan made once is what the nodes are built from."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from antalate_lcm.agent.bma.node import BmaNode
from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.agent.plan import plan_adapter, plan_agent
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Context
from antalate_lcm.runtime.agent import agent_nodes, validate
from antalate_lcm.vehicles.sim import SimAdapter

DOC = {
    "agent": {"name": "p1"},
    "buses": {"lan": "memq://"},
    "hlc": {"autopilot": "sim", "autopilot_params": {"tau": 0.4}},
    "bma": [
        {"name": "operator", "behaviors": [{"plugin": "auto_operator", "params": {"retry": 3.0}}]},
    ],
}


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context.in_process({"lan": "memq://"})
    try:
        yield ctx
    finally:
        ctx.close()


def test_the_nodes_are_built_from_the_plan_validate_made(context: Context) -> None:
    config = parse_config(DOC, "<plan>")
    plan = validate(config)
    assert plan.config is config
    assert plan.adapter.cls is SimAdapter and dict(plan.adapter.params) == {"tau": 0.4}
    assert [b.name for b in plan.bmas[0].behaviors] == ["auto_operator"]
    assert plan.bmas[0].behaviors[0].params.model_dump()["retry"] == 3.0
    nodes = agent_nodes(config, context, plan)
    (bma,) = (n for n in nodes if isinstance(n, BmaNode))
    assert bma.plan is plan.bmas[0]  # not resolved a second time
    (hlc,) = (n for n in nodes if isinstance(n, HlcNode))
    assert isinstance(hlc.adapter, SimAdapter) and hlc.adapter.params == {"tau": 0.4}
    assert hlc.adapter.clock is context.executor.clock


def test_behaviors_are_checked_before_the_adapter_and_both_name_their_key() -> None:
    bad_both = {
        **DOC,
        "hlc": {"autopilot": "nope"},
        "bma": [{"name": "x", "behaviors": [{"plugin": "auto_operator", "params": {"retry": "3"}}]}],
    }
    with pytest.raises(ConfigError) as info:
        plan_agent(parse_config(bad_both, "<plan>"))
    assert info.value.key == "bma[0].behaviors[0].params.retry"
    with pytest.raises(ConfigError) as info:
        plan_adapter(parse_config(bad_both, "<plan>"))
    assert info.value.key == "hlc.autopilot" and "there is no adapter 'nope'" in info.value.expected
