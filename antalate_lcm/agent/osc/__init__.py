"""The Operator Station Client (docs/design.md §9): the agent's HTTP link to an operator station."""

from antalate_lcm.agent.osc.node import OscNode

__all__ = ["OscNode"]
