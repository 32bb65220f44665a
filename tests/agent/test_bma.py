"""The BMA: activation rules (pure), the node on memq://, failure containment and cascading."""

from __future__ import annotations

import time
from typing import Any

import pytest

from antalate_lcm.agent.bma import ActivationRule, Arbiter
from antalate_lcm.core.config import Config
from antalate_lcm.msgs import arbiter_status_t, behavior_state_t, mc_state_t, telemetry_t
from tests.harness.bma import AGENT, Recorder, harness, make_config
from tests.harness.polling import wait_for

REC = "tests.harness.bma:Recorder"
RAISER = "tests.harness.bma:Raiser"


# ---------------------------------------------------------------------- pure rules
def test_rule_without_deactivate_on_is_active_exactly_in_its_states() -> None:
    rule = ActivationRule.of(["MISSION", "TAKEOFF"])
    assert rule.wants_active("MISSION", False) and rule.wants_active("TAKEOFF", True)
    assert not rule.wants_active("RTL", True)
    assert not rule.wants_active("STANDBY", False)


def test_rule_with_deactivate_on_holds_in_other_states() -> None:
    rule = ActivationRule.of(["MISSION"], ["STANDBY", "ERROR"])
    assert rule.wants_active("RTL", True)  # started in MISSION: keeps running through RTL
    assert not rule.wants_active("RTL", False)  # ... but RTL does not start it
    assert not rule.wants_active("STANDBY", True)


def test_arbiter_decides_deactivations_activations_and_notifications() -> None:
    arb = Arbiter({"a": ActivationRule.of(["MISSION"]), "b": ActivationRule.of(["STANDBY", "MISSION"])})
    d = arb.on_state("STANDBY")
    assert (d.activate, d.deactivate, d.notify) == (["b"], [], [])
    arb.activated("b")
    d = arb.on_state("MISSION")
    assert (d.activate, d.deactivate, d.notify) == (["a"], [], ["b"])
    arb.activated("a")
    d = arb.on_state("MISSION")  # periodic republication: nothing to do
    assert (d.activate, d.deactivate, d.notify, d.state_changed) == ([], [], [], False)
    d = arb.on_state("RTL")
    assert d.deactivate == ["a", "b"]


def test_failed_behavior_is_blocked_until_the_state_leaves_its_activate_on() -> None:
    arb = Arbiter({"a": ActivationRule.of(["MISSION"])})
    assert arb.on_state("MISSION").activate == ["a"]
    arb.activated("a")
    arb.failed("a", "boom")
    assert arb.active() == [] and arb.failures() == {"a": "boom"}
    assert arb.on_state("MISSION").activate == []  # the 5 Hz republication does not restart it
    d = arb.on_state("RTL")
    assert d.unblocked == ["a"] and d.activate == []
    assert arb.failures() == {"a": "boom"}  # still reported until it runs again
    assert arb.on_state("MISSION").activate == ["a"]
    arb.activated("a")
    assert arb.failures() == {}


def test_a_settled_state_is_one_to_skip_until_a_standing_changes() -> None:
    """The node skips a state message the arbiter has settled (the MC republishes its state 5 times a
    second): only while `on_state` would decide nothing, and `version` moves with every change the
    status reports, so the node rebuilds its status exactly then."""
    arb = Arbiter({"a": ActivationRule.of(["MISSION"])})
    assert not arb.settled("") and not arb.settled("MISSION")  # nothing decided yet
    v = arb.version
    assert arb.on_state("MISSION").activate == ["a"]
    assert not arb.settled("MISSION") and arb.version > v  # a decision the node carries out
    arb.activated("a")
    v = arb.version
    d = arb.on_state("MISSION")
    assert (d.activate, d.deactivate, d.notify, d.unblocked, d.state_changed) == ([], [], [], [], False)
    assert arb.settled("MISSION") and not arb.settled("RTL") and arb.version == v
    arb.failed("a", "boom")  # any outcome: decide afresh
    assert not arb.settled("MISSION") and arb.version > v
    assert arb.on_state("MISSION").activate == [] and arb.settled("MISSION")  # blocked: nothing to do
    v = arb.version
    d = arb.on_state("RTL")
    assert d.unblocked == ["a"] and not arb.settled("RTL") and arb.version > v
    assert arb.on_state("RTL").unblocked == [] and arb.settled("RTL")
    arb.state = "MISSION"  # set from outside: not the state it settled
    assert not arb.settled("RTL")
    v = arb.version
    assert arb.on_state("MISSION").activate == ["a"]
    arb.activated("a")
    arb.on_state("MISSION")
    arb.deactivated("a")
    assert not arb.settled("MISSION") and arb.version > v
    arb.failed("a", "again")
    arb.on_state("MISSION")
    v = arb.version
    assert arb.retry("a") and not arb.settled("MISSION") and arb.version > v


def test_permanent_failure_is_never_retried() -> None:
    arb = Arbiter({"a": ActivationRule.of(["MISSION"])})
    arb.failed("a", "cannot construct", permanent=True)
    arb.on_state("STANDBY")
    assert arb.on_state("MISSION").activate == []


# ---------------------------------------------------------------------- the node
def _bma(behaviors: list[dict[str, Any]], **kw: Any) -> dict[str, Any]:
    return {"name": kw.pop("name", "main"), "behaviors": behaviors, **kw}


def _raiser(where: str, **bma: Any) -> Config:
    """One BMA whose Raiser behavior, active in MISSION, raises in ``where`` (``bma``: the BMA's keys)."""
    return make_config(
        [_bma([{"plugin": RAISER, "activate_on": ["MISSION"], "params": {"where": where}}], **bma)]
    )


@pytest.fixture(autouse=True)
def _clear_recorder() -> None:
    Recorder.events.clear()


def test_behaviors_follow_the_mc_state_and_status_reports_it() -> None:
    config = make_config(
        [
            _bma(
                [
                    {"plugin": REC, "name": "flying", "activate_on": ["TAKEOFF", "MISSION"]},
                    {"plugin": REC, "name": "grounded", "activate_on": ["STANDBY"]},
                ]
            )
        ]
    )
    with harness(config) as h:
        status = h.record("ARBITER", arbiter="main")
        node = h.bma("main")
        assert wait_for(lambda: status)  # published at start, before any state is known
        assert status[0].arbiter == "main" and status[0].state == "" and status[0].n == 0

        h.mc_state("STANDBY")
        assert wait_for(lambda: h.sync(node.active) == ["grounded"])
        h.mc_state("TAKEOFF")
        assert wait_for(lambda: h.sync(node.active) == ["flying"])
        h.mc_state("MISSION")
        h.mc_state("RTL")
        assert wait_for(lambda: h.sync(lambda: node.state) == "RTL")
        assert h.sync(node.active) == []
        assert Recorder.events == [
            ("grounded", "activate"),
            ("grounded", "deactivate"),
            ("flying", "activate"),
            ("flying", "deactivate"),
        ]
        flying = h.sync(lambda: node.behavior("flying"))
        assert isinstance(flying, Recorder) and flying.states == ["MISSION"]  # on_state while staying active

        mission = next(m for m in status if m.state == "MISSION")
        assert (mission.n, list(mission.active), mission.n_failed) == (1, ["flying"], 0)
        assert status[-1].state == "RTL" and status[-1].n == 0
        assert status[-1].header.agent == AGENT


def test_deactivate_on_keeps_a_behavior_through_other_states() -> None:
    config = make_config([_bma([{"plugin": REC, "activate_on": ["MISSION"], "deactivate_on": ["STANDBY"]}])])
    with harness(config) as h:
        node = h.bma("main")
        h.mc_state("RTL")  # not started by a hold state
        assert wait_for(lambda: h.sync(lambda: node.state) == "RTL")
        assert h.sync(node.active) == []
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active) == ["Recorder"])
        for state in ("RTL", "LAND"):
            h.mc_state(state)
        assert wait_for(lambda: h.sync(lambda: node.state) == "LAND")
        assert h.sync(node.active) == ["Recorder"]
        h.mc_state("STANDBY")
        assert wait_for(lambda: h.sync(node.active) == [])


def test_status_is_republished_periodically() -> None:
    config = make_config([_bma([{"plugin": REC, "activate_on": ["MISSION"]}], republish_hz=20.0)])
    with harness(config) as h:
        status = h.record("ARBITER", arbiter="main")
        node = h.bma("main")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active))
        n0 = len(status)
        assert wait_for(lambda: len(status) >= n0 + 5, timeout=2.0)  # ~20 Hz with no state change
        assert all(m.state == "MISSION" and list(m.active) == ["Recorder"] for m in status[n0:])
        seqs = [m.header.seq for m in status]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)


def test_tick_runs_at_the_configured_rate_only_while_active() -> None:
    config = make_config([_bma([{"plugin": REC, "activate_on": ["MISSION"], "tick_hz": 50.0}])])
    with harness(config) as h:
        node = h.bma("main")
        h.mc_state("MISSION")
        rec = wait_for(lambda: h.sync(lambda: node.behavior("Recorder")))
        assert wait_for(lambda: len(rec.ticks) >= 10)
        h.mc_state("STANDBY")
        assert wait_for(lambda: not h.sync(node.active))
        h.settle()
        n = len(rec.ticks)
        h.settle()
        h.settle()
        assert len(rec.ticks) == n
        assert all(0.0 < dt < 0.2 for dt in rec.ticks)


def test_undefined_mc_state_value_is_ignored() -> None:
    config = make_config([_bma([{"plugin": REC, "activate_on": ["MISSION"]}])])
    with harness(config) as h:
        node = h.bma("main")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active))
        bad = mc_state_t()
        bad.state = 42
        h.probe.publish("MC_STATE", bad)
        h.settle()
        assert h.sync(lambda: node.state) == "MISSION" and h.sync(node.active) == ["Recorder"]


def test_handlers_of_a_past_activation_are_dropped() -> None:
    config = _raiser("handler")
    with harness(config) as h:
        node = h.bma("main")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active))
        h.mc_state("RTL")
        assert wait_for(lambda: not h.sync(node.active))
        h.probe.publish("TELEMETRY", telemetry_t())  # would raise if still subscribed
        h.settle()
        assert h.sync(node.failures) == {}


# ---------------------------------------------------------------------- failure containment
@pytest.mark.parametrize(
    ("where", "reason"),
    [
        ("on_activate", "Raiser: ValueError: cannot start (in on_activate)"),
        ("tick", "Raiser: ZeroDivisionError: tick blew up (in tick)"),
        ("handler", "Raiser: KeyError: 'bad message' (in handler for TELEMETRY)"),
        ("on_state", "Raiser: RuntimeError: cannot handle MISSION (in on_state)"),
    ],
)
def test_a_raising_behavior_is_deactivated_and_reported_while_others_run(where: str, reason: str) -> None:
    config = make_config(
        [
            _bma(
                [
                    {
                        "plugin": RAISER,
                        "activate_on": ["TAKEOFF", "MISSION"],
                        "tick_hz": 50.0,
                        "params": {"where": where},
                    },
                    {"plugin": REC, "activate_on": ["TAKEOFF", "MISSION"], "tick_hz": 50.0},
                ],
                restart_backoff=0,
            )
        ]
    )
    with harness(config) as h:
        status = h.record("ARBITER", arbiter="main")
        node = h.bma("main")
        h.mc_state("TAKEOFF")
        if where == "handler":
            assert wait_for(lambda: "Raiser" in h.sync(node.active) or h.sync(node.failures))
            h.probe.publish("TELEMETRY", telemetry_t())
        if where == "on_state":
            h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.failures)), f"{where} failure not reported"
        assert h.sync(node.active) == ["Recorder"]
        assert wait_for(lambda: any(reason in list(m.failed) for m in status))
        last = status[-1]
        assert list(last.failed) == [reason] and last.n_failed == 1 and list(last.active) == ["Recorder"]
        raiser = h.sync(lambda: node.behavior("Raiser"))
        assert raiser.deactivations == 1  # on_deactivate was attempted
        rec = h.sync(lambda: node.behavior("Recorder"))
        n = len(rec.ticks)
        assert wait_for(lambda: len(rec.ticks) > n + 3)  # the other behavior keeps ticking


def test_failing_constructor_and_on_deactivate_are_reported() -> None:
    config = make_config(
        [
            _bma(
                [
                    {
                        "plugin": RAISER,
                        "name": "broken",
                        "activate_on": ["MISSION"],
                        "params": {"where": "init"},
                    },
                    {
                        "plugin": RAISER,
                        "name": "sticky",
                        "activate_on": ["MISSION"],
                        "params": {"where": "on_deactivate"},
                    },
                    {"plugin": REC, "activate_on": ["MISSION"]},
                ]
            )
        ]
    )
    with harness(config) as h:
        node = h.bma("main")
        assert h.sync(node.failures) == {"broken": "RuntimeError: broken constructor (in __init__)"}
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active) == ["sticky", "Recorder"])
        h.mc_state("STANDBY")
        assert wait_for(lambda: h.sync(node.active) == [])
        assert h.sync(node.failures)["sticky"] == "OSError: cannot stop (in on_deactivate)"
        h.mc_state("MISSION")  # sticky is retried (the state left MISSION); broken never is
        assert wait_for(lambda: h.sync(node.active) == ["sticky", "Recorder"])
        assert "sticky" not in h.sync(node.failures)


def test_failed_behavior_is_retried_only_after_the_state_leaves() -> None:
    config = _raiser("on_activate", republish_hz=50.0, restart_backoff=0)
    with harness(config) as h:
        node = h.bma("main")
        raiser = h.sync(lambda: node.behavior("Raiser"))
        for _ in range(5):  # the MC republishes its state: no restart loop
            h.mc_state("MISSION")
        h.settle()
        assert raiser.deactivations == 1
        h.mc_state("RTL")
        h.mc_state("MISSION")
        assert wait_for(lambda: raiser.deactivations == 2)


def test_failed_behavior_is_restarted_after_a_back_off_that_doubles() -> None:
    """A behavior that met one bad input flies again in the same mission; a broken one is not
    restarted in a tight loop: 0.2 s, then 0.4 s, then 0.8 s (the default is 2 s)."""
    config = _raiser("on_activate", restart_backoff=0.2)
    with harness(config) as h:
        node = h.bma("main")
        raiser = h.sync(lambda: node.behavior("Raiser"))
        started = time.monotonic()
        h.mc_state("MISSION")
        assert wait_for(lambda: raiser.deactivations >= 3, 5)
        # three failures: the first at once, then after 0.2 s and 0.4 s of back-off
        assert time.monotonic() - started >= 0.6
        assert h.sync(node.failures) == {"Raiser": "ValueError: cannot start (in on_activate)"}
        h.mc_state("RTL")  # leaving the state: no restart is pending any more
        n = raiser.deactivations
        assert wait_for(lambda: h.sync(lambda: node.state) == "RTL")
        time.sleep(1.0)  # longer than the pending 0.8 s back-off: it must not start in RTL
        h.settle()
        assert raiser.deactivations == n and h.sync(node.active) == []


def test_a_behavior_that_fails_once_runs_again_in_the_same_state() -> None:
    config = _raiser("handler", restart_backoff=0.1)
    with harness(config) as h:
        node = h.bma("main")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active) == ["Raiser"])
        h.probe.publish("TELEMETRY", telemetry_t())  # one bad message
        assert wait_for(lambda: h.sync(node.failures))
        assert wait_for(lambda: h.sync(node.active) == ["Raiser"], 5)  # back, still in MISSION
        assert h.sync(node.failures) == {}


# ---------------------------------------------------------------------- cascading
#: The topic a switcher's behavior state goes out on, for a cascaded BMA to follow.
SWARM_MODE = {"SWARM_MODE": {"type": "behavior_state_t", "channel": "{agent}/SWARM_MODE"}}


def _switcher(**params: Any) -> dict[str, Any]:
    """The ModeSwitcher behavior (tests.harness.bma), active in MISSION, publishing on SWARM_MODE."""
    entry = {
        "plugin": "tests.harness.bma:ModeSwitcher",
        "activate_on": ["MISSION"],
        "topics": {"MODE": "SWARM_MODE"},
    }
    return {**entry, "params": params} if params else entry


def test_a_behavior_state_drives_a_cascaded_bma() -> None:
    config = make_config(
        [
            _bma([_switcher(after=0.2)], name="root"),
            _bma(
                [
                    {"plugin": REC, "name": "searcher", "activate_on": ["SEARCH"]},
                    {"plugin": REC, "name": "follower", "activate_on": ["FOLLOW"]},
                ],
                name="swarm",
                state_topic="SWARM_MODE",
                states=["SEARCH", "FOLLOW", "IDLE"],
            ),
        ],
        topics=SWARM_MODE,
    )
    with harness(config) as h:
        modes = h.record("SWARM_MODE")
        swarm_status = h.record("ARBITER", arbiter="swarm")
        swarm = h.bma("swarm")
        h.bma("root")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(swarm.active) == ["searcher"])
        assert wait_for(lambda: h.sync(swarm.active) == ["follower"])
        h.mc_state("RTL")  # root deactivates the switcher, which publishes IDLE
        assert wait_for(lambda: h.sync(lambda: swarm.state) == "IDLE")
        assert h.sync(swarm.active) == []
        assert [m.state for m in modes][-1] == "IDLE"
        assert modes[0].header.agent == AGENT
        assert {m.state for m in swarm_status} >= {"SEARCH", "FOLLOW", "IDLE"}
        assert ("searcher", "activate") in Recorder.events and ("follower", "deactivate") in Recorder.events


def test_published_message_type_is_checked() -> None:
    config = make_config([_bma([_switcher()])], topics=SWARM_MODE)
    with harness(config) as h:
        node = h.bma("main")
        beh = h.sync(lambda: node.behavior("ModeSwitcher"))
        with pytest.raises(TypeError, match="carries behavior_state_t"):
            h.sync(lambda: beh.ctx.publish("MODE", arbiter_status_t()))


def test_a_topic_published_again_goes_where_the_lookup_sends_it() -> None:
    """`BehaviorContext.publish` keeps the topic it last published without fields: the topic's
    string again reaches the publisher the lookup gives (its seq counted on), an equal string
    object of another making and a topic with fields take the lookup, and the type is still checked."""
    config = make_config([_bma([_switcher()])], topics=SWARM_MODE)
    with harness(config) as h:
        node = h.bma("main")
        ctx = h.sync(lambda: node.behavior("ModeSwitcher")).ctx
        looked_up = h.sync(lambda: node.publisher(ctx.topic("MODE")))

        def publish(topic: str) -> tuple[Any, int]:
            msg = behavior_state_t()
            msg.state = "SEARCH"
            ctx.publish(topic, msg)
            return ctx._last_pub, msg.header.seq

        first, seq = h.sync(lambda: publish("MODE"))
        again, next_seq = h.sync(lambda: publish("MODE"))
        equal, last_seq = h.sync(lambda: publish("".join(["MO", "DE"])))  # equal, not the same object
        assert first is again is equal is looked_up and (next_seq, last_seq) == (seq + 1, seq + 2)
        with pytest.raises(TypeError, match="carries behavior_state_t"):
            h.sync(lambda: ctx.publish("MODE", arbiter_status_t()))


def test_timers_of_an_activation_are_cancelled_with_it_and_one_shots_are_forgotten() -> None:
    config = make_config(
        [
            _bma(
                [
                    {
                        "plugin": "tests.harness.bma:Delayed",
                        "activate_on": ["MISSION"],
                        "params": {"delay": 0.2},
                    }
                ]
            )
        ]
    )
    with harness(config) as h:
        node = h.bma("main")
        beh = h.sync(lambda: node.behavior("Delayed"))
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active))
        h.mc_state("RTL")  # before the timer fires
        assert wait_for(lambda: not h.sync(node.active))
        time.sleep(0.3)
        h.settle()
        assert beh.fired == 0
        h.mc_state("MISSION")
        assert wait_for(lambda: beh.fired == 1)
        assert h.sync(lambda: beh.ctx._scoped_timers) == []
