"""One agent in the test process (MC + HLC + an ``auto_operator`` BMA on ``memq://``) for any autopilot,
run by `InProcess` (the one runner of nodes in the test's own process).

What the memory-link tests of the Tello and Crazyflie adapters share: the agent is assembled by
`agent_nodes` from a config, as ``antalate agent`` does, and the HLC's adapter can be the test's own
instance (one built on an in-memory link). A probe node records every MC/HLC state change and
``hlc_error_t``, so a test waits for states in order with generous deadlines.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, TypeVar

from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.node import Node, NodeSettings
from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t
from antalate_lcm.runtime.agent import agent_nodes
from antalate_lcm.vehicles.base import VehicleAdapter
from tests.harness.agents import agent_config
from tests.harness.inprocess import InProcess
from tests.harness.polling import wait_for


@dataclass
class Seen:
    t: float
    state: int


#: A MemoryAgent or a subclass: ``start()`` returns the agent it started, typed as itself.
Agent = TypeVar("Agent", bound="MemoryAgent")


class MemoryAgent(InProcess):
    """An agent flying `autopilot` (a name and its params), optionally through the test's `adapter`."""

    def __init__(
        self,
        autopilot: str,
        params: dict[str, Any],
        *,
        hlc: dict[str, Any] | None = None,
        operator: dict[str, Any] | None = None,
        adapter: VehicleAdapter | None = None,
        name: str = "memory",
        safety: dict[str, Any] | None = None,
    ) -> None:
        auto_operator = {
            "plugin": "auto_operator",
            "activate_on": ["STANDBY", "MISSION"],
            "params": {"max_flights": 1, "retry": 0.5, **(operator or {})},
        }
        doc = agent_config(
            name,
            bus="memq://",
            autopilot=autopilot,
            sim=params,
            fast=False,
            takeoff=None,
            hlc=hlc or {},
            safety=safety or {},
            bma=[{"name": "operator", "behaviors": [auto_operator]}],
        )
        super().__init__(parse_config(doc, f"{name}.toml"))
        try:
            self.mc: list[Seen] = []
            self.hlc: list[Seen] = []
            self.errors: list[hlc_error_t] = []
            self.probe = Node(NodeSettings.from_config(self.config), self.context, name="probe")
            #: the agent's nodes as ``antalate agent`` assembles them, started by `start`
            self.assembled = agent_nodes(self.config, self.context)
            if adapter is not None:  # the HLC comes first in agent_nodes
                assert isinstance(self.assembled[0], HlcNode)
                self.assembled[0] = HlcNode(self.config, self.context, adapter)
        except BaseException:
            self.close()  # the executor InProcess started
            raise

    def start(self: Agent) -> Agent:
        self.add(self.probe)
        self.probe.subscribe("MC_STATE", lambda m: self._seen(self.mc, m))
        self.probe.subscribe("HLC_STATE", lambda m: self._seen(self.hlc, m))
        self.probe.subscribe("HLC_ERROR", self.errors.append)
        for node in self.assembled:
            self.add(node)
        return self

    def stop(self) -> None:
        """The agent's nodes, then the probe, then the context (`InProcess.close`)."""
        self.close()

    @staticmethod
    def _seen(into: list[Seen], msg: mc_state_t | hlc_state_t) -> None:
        if not into or into[-1].state != msg.state:
            into.append(Seen(time.monotonic(), msg.state))

    def wait(self, which: str, state: int, timeout: float = 10.0, since: float = 0.0) -> Seen:
        """The first `state` of the MC or HLC seen at or after `since`, waiting up to `timeout` s."""
        seen = self.mc if which == "mc" else self.hlc
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hit = next((s for s in list(seen) if s.state == state and s.t >= since), None)
            if hit is not None:
                return hit
            time.sleep(0.02)
        raise AssertionError(
            f"{which} never reached state {state} (mc {[s.state for s in self.mc]}, "
            f"hlc {[s.state for s in self.hlc]}, errors {[(e.code, e.text) for e in self.errors]})"
        )

    def error(self, code: int, timeout: float = 5.0) -> hlc_error_t:
        """The first ``hlc_error_t`` with `code`, waiting up to `timeout` s."""
        hit = wait_for(lambda: next((e for e in list(self.errors) if e.code == code), None), timeout)
        if hit is None:
            raise AssertionError(f"no hlc_error {code}; got {[(e.code, e.text) for e in self.errors]}")
        return hit

    def states(self, which: str) -> list[int]:
        """Every MC or HLC state change seen, in order."""
        return [s.state for s in (self.mc if which == "mc" else self.hlc)]
