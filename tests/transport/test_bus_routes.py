"""A channel's subscribers as the bus keeps them (core/subscription.py ``Route``), beside the rule
it replaced: each subscription and release used to rebuild the tuple and the set of every
subscriber's type in Python (a thousand agents' start and stop quadratic), now one step of its own."""

from __future__ import annotations

import logging
import random
from functools import partial
from typing import Any

import pytest

from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.bus_connection import BusConnection, Lane
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.subscription import Route, Subscription
from antalate_lcm.msgs import mc_state_t, telemetry_t
from tests.harness.messages import mc_state


def _reference(subs: list[Subscription]) -> tuple[tuple[Subscription, ...], Any]:
    """What ``_Route.set_subs`` (before it) made of the subscribers (the path before this one)."""
    one_type = len({sub.msg_type for sub in subs}) == 1
    return tuple(subs), subs[0].decode if one_type else None


def test_a_route_keeps_the_subscribers_and_decoder_the_full_rebuild_gave() -> None:
    rng = random.Random(7)
    types: list[Any] = [mc_state_t, mc_state_t, mc_state_t, telemetry_t, None]
    for _ in range(300):
        route = Route()
        kept: list[Subscription] = []
        pool = [Subscription("b", "a/X", rng.choice(types), lambda ch, m: None) for _ in range(8)]
        for _ in range(40):
            sub = rng.choice(pool)
            if rng.random() < 0.55 and sub not in kept:
                route.add(sub)
                kept.append(sub)
            else:  # a release, at the end (the stop's order), inside, or of one not there
                if kept and rng.random() < 0.4:
                    sub = kept[-1]
                route.discard(sub)
                if sub in kept:
                    kept.remove(sub)
            if kept:
                assert (route.subs, route.decode) == _reference(kept)
            else:
                assert (route.subs, route.decode) == ((), None)


def _append(got: list[int], i: int, _channel: str, _msg: object) -> None:
    got.append(i)


def test_releases_in_any_order_leave_the_channel_delivered_to_the_rest() -> None:
    """A thousand agents' nodes on one channel (the swarm's commands), released last-first (the
    stop), then first-first; every message reaches exactly those still subscribed, once."""
    b = Buses({"test": "memq://"})
    try:
        got: list[int] = []
        subs = [b.subscribe("test", "SWARM/X", mc_state_t, partial(_append, got, i)) for i in range(50)]
        conn = b._by_name["test"]
        assert conn._routes["SWARM/X"].decode is not None, "one type: one decoder"
        for sub in reversed(subs[25:]):
            b.unsubscribe(sub)
            b.unsubscribe(sub)  # again: nothing (a BMA's behaviors hand theirs back after the node)
        for sub in subs[:10]:
            b.unsubscribe(sub)
        ex = b.executor
        ex.run_sync(lambda: b.publish("test", "SWARM/X", mc_state(1, 1)))
        ex.run_sync(lambda: None)
        assert got == list(range(10, 25))
        assert conn._routes["SWARM/X"].lcm_sub is None, "memq:// goes through the loop, never liblcm"
        for sub in subs[10:25]:
            b.unsubscribe(sub)
        assert "SWARM/X" not in conn._routes
    finally:
        b.close()


class _LookedUp(BusConnection):
    """The memq:// path before lanes: every message looks its channel's route up in the table of
    every channel, and its pattern subscribers are matched again (what `Lane` keeps instead)."""

    def lane(self, channel: str) -> Lane:
        return Lane(self, channel, self._routes.get(channel))  # fresh: nothing kept


def _play(seed: int, looked_up: bool) -> list[tuple[int, str, object]]:
    """A random run of subscriptions, releases and publishes (by a publisher's sender and by
    ``Buses.publish``), several in one loop turn so that deliveries meet changes made after the
    publish; every delivery as (subscription, channel, what it got)."""
    rng = random.Random(seed)
    ex = Executor()
    b = Buses({"test": "memq://"})
    b.attach(ex)
    if looked_up:
        conn = _LookedUp("memq://", 100, RateLimitedLog(logging.getLogger("test")), lambda: ex)
        b._connections["memq://"] = b._by_name["test"] = conn
    ex.start()
    got: list[tuple[int, str, object]] = []
    live: list[Subscription] = []
    channels = ["a/MC_STATE", "b/MC_STATE", "a/TELEMETRY", "SWARM/X"]
    patterns = [r"(?P<agent>[^/]+)/MC_STATE", ".*", r"a/.*"]
    lanes: dict[str, Lane | None] = {}
    made = 0

    def record(i: int, channel: str, msg: object) -> None:
        got.append((i, channel, msg.header.seq if isinstance(msg, mc_state_t) else msg))

    def step() -> None:
        nonlocal made
        for _ in range(rng.randint(1, 6)):
            op = rng.random()
            if op < 0.25:
                regex = rng.random() < 0.3
                channel = rng.choice(patterns if regex else channels)
                msg_type = rng.choice([mc_state_t, None])
                live.append(b.subscribe("test", channel, msg_type, partial(record, made), regex=regex))
                made += 1
            elif op < 0.4 and live:
                b.unsubscribe(live.pop(rng.randrange(len(live))))
            else:
                channel = rng.choice(channels)
                data = mc_state(1, rng.randrange(1000)).encode() if rng.random() < 0.8 else b"junk"
                if rng.random() < 0.5 or looked_up:  # (the reference: every message looked up)
                    b.publish("test", channel, data)
                else:  # as a publisher does, its lane kept from the first message
                    if channel not in lanes:
                        lanes[channel] = b.lane("test", channel)
                    lane = lanes[channel]
                    assert lane is not None
                    lane.publish(data)

    try:
        for _ in range(150):
            ex.run_sync(step)
        ex.run_sync(lambda: None)
    finally:
        ex.stop()
        b.close()
    return got


@pytest.mark.parametrize("seed", range(6))
def test_a_channels_lane_delivers_what_looking_its_route_up_per_message_did(seed: int) -> None:
    lanes = _play(seed, looked_up=False)
    assert len(lanes) > 100
    assert lanes == _play(seed, looked_up=True)


def test_a_message_only_handler_gets_what_a_closure_dropping_the_channel_got() -> None:
    """`Node.subscribe` without admission hands its handler to the bus (``msg_only``) instead of
    a closure ``lambda channel, msg: handler(msg)``: beside one, on a shared route (one decode),
    a mixed one (raw beside typed), after garbage (one decode error, neither called), and raising
    (logged, the next subscriber still called); a pattern cannot take it."""
    b = Buses({"test": "memq://"})
    try:
        got: list[tuple[str, object]] = []

        def closure(ch: str, m: object) -> None:
            got.append(("closure", m))

        def bare(m: object) -> None:
            got.append(("bare", m))

        def raising(m: object) -> None:
            raise RuntimeError("a handler's bug")

        b.subscribe("test", "a/MC_STATE", mc_state_t, closure)
        b.subscribe("test", "a/MC_STATE", mc_state_t, raising, msg_only=True)
        b.subscribe("test", "a/MC_STATE", mc_state_t, bare, msg_only=True)
        ex = b.executor
        for data in (mc_state(1, 1).encode(), b"garbage", mc_state(1, 2).encode()):
            ex.run_sync(partial(b.publish, "test", "a/MC_STATE", data))
        ex.run_sync(lambda: None)
        assert [who for who, _ in got] == ["closure", "bare"] * 2
        assert got[0][1] is got[1][1] and got[2][1] is got[3][1], "one decode, the same message"
        assert b.decode_errors() == {"a/MC_STATE": 1}
        got.clear()
        b.subscribe("test", "a/MC_STATE", None, lambda ch, d: got.append(("raw", d)))
        ex.run_sync(lambda: b.publish("test", "a/MC_STATE", mc_state(1, 3).encode()))
        ex.run_sync(lambda: None)
        assert [who for who, _ in got] == ["closure", "bare", "raw"] and got[0][1] is got[1][1]
        with pytest.raises(ValueError, match="exact channel"):
            b.subscribe("test", ".*", None, bare, regex=True, msg_only=True)
    finally:
        b.close()
