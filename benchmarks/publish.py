"""What a node's publish costs in its own process: stamping the header, sealing, handing the bytes over.

The round trip (``benchmarks/bus.py``) is 70-100 us, its spread at this machine's load tens of us: a
change of the node's publish path by tens of nanoseconds does not show there. This measures the path
alone, without a bus (each bus's send function is a no-op): ``Node.publish(topic, msg)``, which looks
the topic's publisher up, and the publisher handle a hot path keeps (``Node.publisher(topic)``, then
``publish(msg)``: the HLC's telemetry, the states, a behavior's commands), unsigned and signed.

    .venv/bin/python benchmarks/publish.py
    PYTHONPATH=/path/to/baseline .venv/bin/python benchmarks/publish.py   # another checkout, same session

The best of ``--rounds`` rounds of ``--n`` messages (the best is the least disturbed by the machine's
other work). A checkout from before publisher handles (issue 26) measures ``Node.publish`` alone.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import antalate_lcm
from antalate_lcm.core import node as node_module
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Context, Node
from antalate_lcm.msgs import telemetry_t


def _node(key: str) -> tuple[Node, Context]:
    config = parse_config(
        {"agent": {"name": "bench"}, "buses": {"lan": "memq://"}, "security": {"swarm_key": key}}
    )
    context = Context.create(config)
    buses: Any = getattr(context, "buses", None)  # None: a checkout from before issue 26 named it `bus`
    if buses is None:
        buses = context.bus
    buses.sender = lambda _name: lambda _channel, _data: None
    settings: Any = getattr(node_module, "NodeSettings", None)  # None: a checkout from before it
    first: Any = settings.from_config(config) if settings is not None else config
    node = Node(first, context, name="bench")
    return node, context


def _best(fn: Callable[[Any], Any], n: int, rounds: int) -> float:
    msg = telemetry_t()
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(n):
            fn(msg)
        best = min(best, (time.perf_counter() - start) / n)
    return best * 1e9


def _ways(node: Node) -> dict[str, Callable[[Any], Any]]:
    """The node's ways to publish TELEMETRY: by topic, and through its handle where there is one."""
    ways: dict[str, Callable[[Any], Any]] = {"Node.publish": lambda m: node.publish("TELEMETRY", m)}
    if hasattr(node, "publisher"):
        ways["handle"] = node.publisher("TELEMETRY").publish
    return ways


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=20_000, help="messages per round")
    parser.add_argument("--rounds", type=int, default=40, help="rounds; the best is shown")
    args = parser.parse_args()
    print(f"antalate from {antalate_lcm.__file__.rsplit('/antalate_lcm/', 1)[0]}")
    for label, key in (("unsigned", ""), ("signed", "benchmark key")):
        node, context = _node(key)
        try:
            ways = _ways(node)
            line = "  ".join(f"{way} {_best(fn, args.n, args.rounds):5.0f} ns" for way, fn in ways.items())
            print(f"  {label:9} {line}")
        finally:
            context.close()


if __name__ == "__main__":
    main()
