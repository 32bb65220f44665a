"""Deprecated: import from ``tests.harness.agents``. Where tests imported these names from before
tests/harness/ gathered the helpers; they still work for one release (a behavior package's tests may
have copied the old path from docs/behaviors.md), with a DeprecationWarning that names the new place."""

import warnings

from tests.harness.agents import FAST_SIM as FAST_SIM
from tests.harness.agents import AgentProcesses as AgentProcesses
from tests.harness.agents import agent_config as agent_config

warnings.warn(
    "tests.agent_harness is deprecated: import from tests.harness.agents", DeprecationWarning, stacklevel=2
)
