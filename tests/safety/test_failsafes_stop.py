"""A graceful stop of a flying agent raises no alarm (issue 12, item 6).

`Node.stop` used to run ``on_stop`` (which closes the autopilot) before cancelling the node's timers,
so the HLC's control loop could poll a closed adapter and report a CRITICAL LINK_LOST / LLC_DOWN on
Ctrl-C (4 runs in 9). Here an in-process agent is started, flown, and stopped the way ``antalate
agent`` stops it on SIGINT (`run_until_signal`), 20 times, while airborne: not one ERROR or CRITICAL
log line may appear, and the stop must leave no timer running.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator

import pytest

from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.agent.mc.node import McNode
from antalate_lcm.core.config import AgentConfig, Config, HlcConfig
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import operator_cmd_t
from antalate_lcm.runtime.agent import agent_nodes
from antalate_lcm.runtime.launch import run_until_signal
from antalate_lcm.wire.vocabulary import HlcState, McState
from tests.harness.polling import wait_for

STOPS = 20


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture
def alarms() -> Iterator[list[logging.LogRecord]]:
    handler = _Collect()
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        yield handler.records
    finally:
        root.removeHandler(handler)


def _config(i: int) -> Config:
    return Config(
        agent=AgentConfig(name=f"stopper{i}"),
        buses={"lan": "memq://"},
        hlc=HlcConfig(
            default_takeoff_altitude=2.0,
            autopilot_params={"climb_rate": 5.0, "time_scale": 4.0},
        ),
    )


def _fly_and_stop(i: int) -> None:
    config = _config(i)
    context = Context.in_process(config.buses)
    nodes = agent_nodes(config, context)
    hlc = next(n for n in nodes if isinstance(n, HlcNode))
    mc = next(n for n in nodes if isinstance(n, McNode))
    stop = threading.Event()
    runner = threading.Thread(target=run_until_signal, args=(context, nodes), kwargs={"stop_event": stop})
    runner.start()
    try:
        assert wait_for(lambda: mc.state is McState.STANDBY, 10), f"run {i}: MC {mc.state.name}"
        cmd = operator_cmd_t()
        cmd.command = operator_cmd_t.TAKEOFF
        Node(NodeSettings.from_config(config), context, name="operator").publish("OPERATOR_CMD", cmd)
        assert wait_for(lambda: hlc.state is HlcState.AIRBORNE and mc.state is McState.MISSION, 10), (
            f"run {i}: HLC {hlc.state.name}, MC {mc.state.name}"
        )
        assert hlc.adapter.state().in_air
    finally:
        stop.set()  # what SIGINT does
        runner.join(15)
    assert not runner.is_alive(), f"run {i}: the agent did not stop"
    assert hlc.state is HlcState.AIRBORNE, f"run {i}: the stop itself moved the HLC to {hlc.state.name}"
    assert not hlc._timers and not hlc._subs and not mc._timers and not mc._subs


def test_stopping_a_flying_agent_20_times_raises_no_alarm(alarms: list[logging.LogRecord]) -> None:
    for i in range(STOPS):
        _fly_and_stop(i)
    lines = [f"{r.name} {r.levelname}: {r.getMessage()}" for r in alarms]
    assert lines == [], "\n".join(lines)
