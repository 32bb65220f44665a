"""Node.ticker: jobs whose rates divide the fastest share its timer, at their own rates; others get their own.

The HLC runs control, telemetry and its state on one ticker (20, 10 and 5 Hz by default) and the MC
its tick and its state (10 and 5 Hz) on the same one: 20 timer runs a second per agent instead of 50.
The rates are checked as ratios of runs of one timer (exact whatever the machine's load), never
against a clock.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator

import pytest

from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.agent.mc.node import McNode
from antalate_lcm.core.config import AgentConfig, Config
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.core.timers import Ticker
from antalate_lcm.runtime.agent import agent_nodes
from tests.harness.polling import wait_for


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context.in_process({"lan": "memq://"})
    ctx.executor.start()
    try:
        yield ctx
    finally:
        ctx.close()


def _node(context: Context, name: str = "ticker") -> Node:
    return Node(
        NodeSettings.from_config(Config(agent=AgentConfig(name=name), buses={"lan": "memq://"})), context
    )


def test_divisor_rates_share_one_timer_and_run_at_their_rates(context: Context) -> None:
    node = _node(context)
    now = [0.0]
    runs: dict[str, list[float]] = {"fast": [], "half": [], "quarter": []}

    def job(name: str) -> Callable[[], None]:
        return lambda: runs[name].append(now[0])

    context.executor.run_sync(
        lambda: node.ticker(
            20.0, [(20.0, job("fast")), (10.0, job("half")), (5.0, job("quarter"))], clock=lambda: now[0]
        )
    )
    assert len(node._timers) == 1
    node._timers[0].cancel()  # driven by hand below, on a clock of the test's own
    tick = node._timers[0].fn
    for k in range(20):  # 1 s on time, the timer's millisecond slots a little late or early
        now[0] = 0.05 * k + (0.001 if k % 3 else -0.0005)
        tick()
    assert len(runs["fast"]) == 20 and len(runs["half"]) == 10 and len(runs["quarter"]) == 5
    assert runs["half"] == [t for i, t in enumerate(runs["fast"]) if i % 2 == 0]
    # A loaded executor skips runs of the timer (1.05, 1.10, 1.25, 1.30 never come): each job
    # still runs on the runs that remain when its period came round, late rather than lost, and
    # keeps its schedule as a timer of its own would (Executor: due + period unless a period behind).
    for t in (1.0, 1.15, 1.2, 1.35, 1.4, 1.45, 1.5):
        now[0] = t
        tick()
    assert runs["half"][10:] == [1.0, 1.15, 1.2, 1.35, 1.4, 1.5]
    assert runs["quarter"][5:] == [1.0, 1.2, 1.4]
    # A whole period behind: one run, not a burst, and the schedule restarts from there.
    now[0] = 2.0
    tick()
    now[0] = 2.05
    tick()
    assert runs["half"][-1] == 2.0 and runs["quarter"][-1] == 2.0


def test_a_rate_that_does_not_divide_gets_a_timer_of_its_own(context: Context) -> None:
    node = _node(context)
    runs = {"fast": 0, "odd": 0, "faster": 0}
    context.executor.run_sync(
        lambda: node.ticker(
            100.0,
            [
                (100.0, lambda: runs.__setitem__("fast", runs["fast"] + 1)),
                (30.0, lambda: runs.__setitem__("odd", runs["odd"] + 1)),
                (300.0, lambda: runs.__setitem__("faster", runs["faster"] + 1)),
            ],
        )
    )
    assert len(node._timers) == 3
    assert wait_for(lambda: min(runs.values()) >= 3, 20)
    for timer in node._timers:
        timer.cancel()


def test_a_raising_job_is_logged_and_the_others_still_run(
    context: Context, caplog: pytest.LogCaptureFixture
) -> None:
    node = _node(context)
    runs = {"after": 0}

    def broken() -> None:
        raise RuntimeError("job bug")

    with caplog.at_level(logging.ERROR):
        context.executor.run_sync(
            lambda: node.ticker(
                200.0, [(200.0, broken), (100.0, lambda: runs.__setitem__("after", runs["after"] + 1))]
            )
        )
        assert wait_for(lambda: runs["after"] >= 3, 20)
    for timer in node._timers:
        timer.cancel()
    assert any("job bug" in (r.exc_text or "") or "broken" in r.getMessage() for r in caplog.records)


def test_jobs_of_two_nodes_share_the_runs_of_their_period_and_leave_with_their_node() -> None:
    ticker = Ticker(20.0)
    log = logging.getLogger("test.ticker")
    runs: list[str] = []
    hlc, mc = object(), object()
    ticker.add(hlc, [(20.0, lambda: runs.append("control")), (10.0, lambda: runs.append("telemetry"))], log)
    ticker.run(0.0)
    ticker.run(0.05)
    # The MC joins on an odd run: its 10 Hz job runs with the telemetry, not on the runs between.
    ticker.add(mc, [(10.0, lambda: runs.append("mc tick")), (5.0, lambda: runs.append("mc state"))], log)
    runs.clear()
    for k in range(2, 6):
        ticker.run(0.05 * k)
    assert runs == [
        "control", "telemetry", "mc tick", "mc state",
        "control",
        "control", "telemetry", "mc tick",
        "control",
    ]  # fmt: skip
    assert not ticker.remove(hlc)  # the MC's jobs stay
    runs.clear()
    for k in range(6, 10):
        ticker.run(0.05 * k)
    assert runs == ["mc tick", "mc state", "mc tick"]
    assert ticker.remove(mc)


def test_an_agent_at_the_default_rates_runs_one_timer(context: Context) -> None:
    """HLC: control, telemetry and state; MC: tick and state; all on the HLC's 20 Hz timer."""
    config = Config(agent=AgentConfig(name="t1"), buses={"lan": "memq://"})
    nodes = agent_nodes(config, context)
    hlc = next(n for n in nodes if isinstance(n, HlcNode))
    mc = next(n for n in nodes if isinstance(n, McNode))
    for n in nodes:
        n.start()
    try:
        assert len(hlc._timers) == 1 and not mc._timers
        assert context.tickers["t1"].timer is hlc._timers[0]
        # The MC's tick and state run on it: it hears the HLC and the HLC hears it.
        assert wait_for(lambda: hlc.connected and mc.state.name == "STANDBY", 20)
    finally:
        for n in reversed(nodes):
            n.stop()
    assert not context.tickers and not hlc._timers


def test_the_mc_keeps_its_jobs_when_its_hlc_stops_and_the_hlc_joins_again(context: Context) -> None:
    config = Config(agent=AgentConfig(name="t2"), buses={"lan": "memq://"})
    nodes = agent_nodes(config, context)
    hlc = next(n for n in nodes if isinstance(n, HlcNode))
    mc = next(n for n in nodes if isinstance(n, McNode))
    for n in nodes:
        n.start()
    try:
        assert wait_for(lambda: mc.state.name == "STANDBY", 20)
        ticker = context.tickers["t2"]
        hlc.stop()
        # The MC's 10 Hz tick still runs on the stopped HLC's timer: it notices the silence.
        assert wait_for(lambda: mc.state.name == "HLC_LOST", 30)
        assert not ticker.timer.cancelled and not hlc._timers
        hlc.start()
        assert wait_for(lambda: mc.state.name == "STANDBY", 30)
        assert context.tickers == {"t2": ticker} and hlc._tickers == [ticker] and ticker.base is not None
    finally:
        for n in reversed(nodes):
            n.stop()
    assert not context.tickers and ticker.timer.cancelled


class _Timer:
    """The executor's side of a ticker's timer, by hand: its due time and its skips (Timer)."""

    def __init__(self, due: float) -> None:
        self.due = due
        self.skips = 0


def test_the_cycle_runs_what_the_due_times_would_through_skips_and_changes() -> None:
    """A ticker on its timer runs its jobs from a cycle; one given ``now`` by the due times alone:
    the same runs through skipped runs, a node joining and one leaving."""
    log = logging.getLogger("test.ticker")
    seen: dict[str, list[tuple[int, str]]] = {"cycle": [], "due": []}
    run = [0]

    def job(way: str, name: str) -> Callable[[], None]:
        return lambda: seen[way].append((run[0], name))

    def jobs(way: str, node: str, rates: tuple[float, ...]) -> list[tuple[float, Callable[[], None]]]:
        return [(rate, job(way, f"{node}@{rate:g}")) for rate in rates]

    cycled, by_due = Ticker(20.0), Ticker(20.0)
    hlc, mc = object(), object()
    for ticker, way in ((cycled, "cycle"), (by_due, "due")):
        ticker.add(hlc, jobs(way, "hlc", (20.0, 10.0, 5.0)), log)
    timer = cycled.timer = _Timer(1000.0)
    cycles = 0
    for k in range(60):
        run[0] = k
        if k == 7:  # the MC joins on an odd run
            cycled.add(mc, jobs("cycle", "mc", (10.0, 5.0, 2.5)), log)
            by_due.add(mc, jobs("due", "mc", (10.0, 5.0, 2.5)), log)
        if k == 41:
            cycled.remove(hlc)
            by_due.remove(hlc)
        due = timer.due
        cycled.run()
        by_due.run(due)
        cycles += cycled.cycle is not None
        # As Executor._run_slot re-arms it: runs 13-14 and 30 come over a period late (skipped).
        late = {13: 0.06, 14: 0.12, 30: 0.051}.get(k, 0.0)
        timer.due = due + 0.05 if late < 0.05 else due + late + 0.05
        timer.skips += late >= 0.05
    assert seen["cycle"] == seen["due"]
    assert cycles >= 30  # all but the runs after a change, and a cycle's worth after a skip
    assert ("hlc@20", 40) in [(n, r) for r, n in seen["cycle"]] and all(
        not n.startswith("hlc") for r, n in seen["cycle"] if r >= 41
    )


@pytest.mark.parametrize(("tick", "on_cycle"), [(1, False), (3, True)])
def test_a_node_stopped_by_a_job_of_the_run_runs_none_of_its_jobs_after(tick: int, on_cycle: bool) -> None:
    """The MC's ``tick``-th tick stops the HLC: on the first run by the due times, the third on the cycle."""
    log = logging.getLogger("test.ticker")
    ticker = Ticker(20.0)
    ticker.timer = _Timer(1000.0)
    runs: list[str] = []
    cycling: list[bool] = []
    hlc, mc = object(), object()

    def mc_tick() -> None:
        runs.append("mc tick")
        if runs.count("mc tick") == tick:
            cycling.append(ticker.cycle is not None)
            ticker.remove(hlc)

    ticker.add(mc, [(10.0, mc_tick)], log)
    ticker.add(hlc, [(20.0, lambda: runs.append("control")), (10.0, lambda: runs.append("telemetry"))], log)
    for _ in range(2 * tick + 2):
        ticker.run()
        ticker.timer.due += 0.05
    # Control, then the MC's tick, which stops the HLC: the HLC's telemetry of that run, after the
    # tick in their group, does not run, nor anything of the HLC's after; the MC's tick goes on.
    before = ["control", "mc tick", "telemetry", "control"] * (tick - 1)
    assert cycling == [on_cycle]
    assert runs == [*before, "control", "mc tick", "mc tick"]
