"""The Behavior Module Arbiter (docs/design.md §8): activation rules, config validation and the node.

``validate_bma_config(config)`` checks every ``[[bma]]`` before nodes start; ``BmaNode`` runs one.
"""

from antalate_lcm.agent.bma.arbiter import ActivationRule, Arbiter
from antalate_lcm.agent.bma.node import BmaNode
from antalate_lcm.agent.bma.plan import BehaviorPlan, BmaPlan, plan_bma, validate_bma_config

__all__ = [
    "ActivationRule",
    "Arbiter",
    "BehaviorPlan",
    "BmaNode",
    "BmaPlan",
    "plan_bma",
    "validate_bma_config",
]
