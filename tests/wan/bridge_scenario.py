"""Two-bridge scenarios run inside a private network namespace (real multicast on lo, a real Zenoh
router on loopback); prints one JSON line of what every observer received and what each bridge did.

    python -m tests.wan.bridge_scenario two-sites|one-lan PORT

``two-sites``: LAN A <-> bridge A <-> Zenoh <-> bridge B <-> LAN B; 40 messages from each of LAN A,
LAN B and a Zenoh publisher, and 60 telemetry messages from LAN B capped at 5/s towards Zenoh.
``one-lan``: two bridges join the same LAN to Zenoh (a redundant site gateway); then the one that
forwards to the LAN stops, and the other takes over.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections import Counter
from typing import Any

import zenoh

from antalate_lcm.apps.bridge import Bridge, BridgeConfig
from antalate_lcm.core.bus import Buses
from antalate_lcm.msgs import mc_state_t, telemetry_t
from antalate_lcm.runtime.router import router_config

LAN_A = "udpm://239.255.76.67:7667?ttl=0"
LAN_B = "udpm://239.255.76.69:7669?ttl=0"
N = 40
TELEMETRY = 60
RATE = 5.0


def msg(origin: int, seq: int) -> bytes:
    m = mc_state_t()
    m.state = origin
    m.header.seq = seq
    m.header.utime = int(time.time() * 1e6)
    return m.encode()


class Observer:
    """Every datagram of a bus, raw, counted by (channel, bytes)."""

    def __init__(self, bus: Buses, name: str) -> None:
        self.copies: Counter[tuple[str, bytes]] = Counter()
        self.order: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        bus.subscribe(name, ".*", None, self._on, regex=True)

    def _on(self, channel: str, data: bytes) -> None:
        with self.lock:
            self.copies[(channel, data)] += 1
            self.order.append((channel, data))

    def has(self, channel: str, data: bytes) -> bool:
        with self.lock:
            return self.copies[(channel, data)] > 0

    def summary(self, prefix: str) -> dict[str, Any]:
        with self.lock:
            mine = {k: v for k, v in self.copies.items() if k[0].startswith(prefix)}
        return {
            "distinct": len(mine),
            "max_copies": max(mine.values(), default=0),
            "total": sum(mine.values()),
        }


def wait(pred: Any, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.02)
    return False


def bridge(lan: str, wan: str, site: str, limits: list[dict[str, Any]] | None = None) -> Bridge:
    config = BridgeConfig.model_validate(
        {
            "buses": {"lan": lan, "wan": wan},
            "bridge": {"between": ["lan", "wan"], "site": site, "limit": limits or []},
        }
    )
    b = Bridge(config)
    b.start()
    return b


def settle(bus: Buses, bus_name: str, observers: list[Observer]) -> None:
    """Probe until every observer hears the publisher (subscriptions reach the router asynchronously)."""
    i = 0

    def probe() -> bool:
        nonlocal i
        i += 1
        data = msg(99, i)
        bus.publish(bus_name, "probe/X", data)
        return all(wait(lambda o=o: o.has("probe/X", data), 0.3) for o in observers)

    if not wait(probe, 30):
        raise SystemExit("the bridges never carried a probe")


def two_sites(port: int) -> dict[str, Any]:
    wan = f"zenoh://?connect=tcp/127.0.0.1:{port}"
    limit = [{"channel": ".*/TELEMETRY", "to": "wan", "rate": RATE}]
    # Both sites' LANs use the same URL form in the field; here two groups stand for two LANs.
    bridges = [bridge(LAN_A, wan, "site-a"), bridge(LAN_B, wan, "site-b", limit)]
    bus = Buses({"a": LAN_A, "b": LAN_B, "w": wan})
    obs = {"a": Observer(bus, "a"), "b": Observer(bus, "b"), "w": Observer(bus, "w")}
    for name in ("a", "b", "w"):
        settle(bus, name, [o for k, o in obs.items() if k != name])
    sent = []
    for i in range(N):
        for origin, name in ((1, "a"), (2, "b"), (3, "w")):
            data = msg(origin, i)
            bus.publish(name, f"test/{name}", data)
            sent.append((f"test/{name}", data))
    all_arrived = wait(lambda: all(o.has(ch, d) for o in obs.values() for ch, d in sent), 30)
    # Telemetry at full speed from site B; the uplink cap lets 5/s through, the newest last.
    t0 = time.monotonic()
    last = b""
    for i in range(TELEMETRY):
        t = telemetry_t()
        t.header.seq = i
        last = t.encode()
        bus.publish("b", "bravo/TELEMETRY", last)
        time.sleep(0.01)
    newest_arrived = wait(lambda: obs["w"].has("bravo/TELEMETRY", last), 10)
    elapsed = time.monotonic() - t0
    # A fence through every path: anything still echoing would be counted before it.
    fence = [("fence/a", "a", msg(7, 1)), ("fence/b", "b", msg(7, 2)), ("fence/w", "w", msg(7, 3))]
    for ch, name, data in fence:
        bus.publish(name, ch, data)
    fenced = wait(lambda: all(o.has(ch, d) for o in obs.values() for ch, _, d in fence), 20)
    with obs["w"].lock:
        tel = [d for ch, d in obs["w"].order if ch == "bravo/TELEMETRY"]
    out = {
        "all_arrived": all_arrived,
        "fenced": fenced,
        "observers": {k: o.summary("test/") for k, o in obs.items()},
        "telemetry": {
            "sent": TELEMETRY,
            "received": len(tel),
            "elapsed": elapsed,
            "rate": RATE,
            "newest_arrived": newest_arrived,
            "last_is_newest": bool(tel) and tel[-1] == last,
        },
        "telemetry_on_b": obs["b"].summary("bravo/")["total"],
        "bridges": [b.stats() for b in bridges],
    }
    for b in bridges:
        b.close()
    bus.close()
    return out


def one_lan(port: int) -> dict[str, Any]:
    wan = f"zenoh://?connect=tcp/127.0.0.1:{port}"
    bridges = [bridge(LAN_A, wan, "site-a"), bridge(LAN_A, wan, "site-a")]
    bus = Buses({"a": LAN_A, "w": wan})
    obs = {"a": Observer(bus, "a"), "w": Observer(bus, "w")}
    settle(bus, "a", [obs["w"]])
    settle(bus, "w", [obs["a"]])
    sent_a = [("test/a", msg(1, i)) for i in range(N)]
    sent_w = [("test/w", msg(3, i)) for i in range(N)]
    for (ca, da), (cw, dw) in zip(sent_a, sent_w, strict=True):
        bus.publish("a", ca, da)
        bus.publish("w", cw, dw)
    arrived = wait(
        lambda: all(obs["w"].has(c, d) for c, d in sent_a) and all(obs["a"].has(c, d) for c, d in sent_w), 30
    )
    fence = [("fence/a", "a", msg(7, 1)), ("fence/w", "w", msg(7, 3))]
    for ch, name, data in fence:
        bus.publish(name, ch, data)
    fenced = wait(lambda: all(o.has(ch, d) for o in obs.values() for ch, _, d in fence), 20)
    with obs["w"].lock:
        w_from_a = max((v for k, v in obs["w"].copies.items() if k[0] == "test/a"), default=0)
    with obs["a"].lock:
        a_from_w = [v for k, v in obs["a"].copies.items() if k[0] == "test/w"]
        a_own = [v for k, v in obs["a"].copies.items() if k[0] == "test/a"]
    stats = [b.stats() for b in bridges]
    # The forwarding bridge goes away: the other one takes over (its session's token is gone).
    leader = min(bridges, key=lambda b: b.id)
    leader.close()
    settle(bus, "w", [obs["a"]])
    after = [("test/after", msg(4, i)) for i in range(N)]
    for c, d in after:
        bus.publish("w", c, d)
    took_over = wait(lambda: all(obs["a"].has(c, d) for c, d in after), 30)
    fence2 = ("fence/w2", msg(7, 4))
    bus.publish("w", *fence2)
    fenced2 = wait(lambda: obs["a"].has(*fence2), 20)
    with obs["a"].lock:
        a_after = [v for k, v in obs["a"].copies.items() if k[0] == "test/after"]
    out = {
        "arrived": arrived,
        "fenced": fenced and fenced2,
        "wan_copies_of_a_lan_message": w_from_a,
        "lan_copies_of_a_wan_message": max(a_from_w, default=0),
        "lan_copies_of_a_lan_message": max(a_own, default=0),
        "took_over": took_over,
        "lan_copies_after_failover": max(a_after, default=0),
        "bridges": stats,
    }
    for b in bridges:
        b.close()
    bus.close()
    return out


def main() -> None:
    scenario, port = sys.argv[1], int(sys.argv[2])
    router = zenoh.open(router_config([f"tcp/127.0.0.1:{port}"], 3000))
    try:
        result = two_sites(port) if scenario == "two-sites" else one_lan(port)
    finally:
        router.close()
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
