"""A channel's subscribers as the bus keeps them (core/subscription.py ``Route``), beside the rule
it replaced: each subscription and release used to rebuild the tuple and the set of every
subscriber's type in Python (a thousand agents' start and stop quadratic), now one step of its own."""

from __future__ import annotations

import random
from functools import partial
from typing import Any

from antalate_lcm.core.bus import Buses
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
