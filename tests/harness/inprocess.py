"""Nodes in the test's own process: one context (the config's buses, a started executor) and the
nodes a test adds to it, stopped newest first, then the context, whatever happens.

The agent runner in one process: the BMA tests' `Harness` (tests/harness/bma.py) and the signing
tests' `Swarm` (tests/core/test_security_node.py) are this with their own probes and attackers; a whole
agent assembled as ``antalate agent`` does is `tests.harness.memory_agent.MemoryAgent`, an `InProcess` too.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context, Node

N = TypeVar("N", bound=Node)
Self = TypeVar("Self", bound="InProcess")


class InProcess:
    def __init__(self, config: Config) -> None:
        self.config = config
        self.context = Context(Buses(config.buses), Executor())
        self.context.executor.start()
        self.nodes: list[Node] = []

    def add(self, node: N) -> N:
        """``node`` started, and stopped by `close`."""
        node.start()
        self.nodes.append(node)
        return node

    def sync(self, fn: Callable[[], Any]) -> Any:
        """``fn()`` on the executor's thread, where the nodes' handlers run."""
        return self.context.executor.run_sync(fn)

    def close(self) -> None:
        for node in reversed(self.nodes):
            node.stop()
        self.context.close()

    def __enter__(self: Self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
