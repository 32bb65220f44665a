"""Where tests imported the agent config builder and process runner from before tests/harness/
gathered them; the same names, still importable from here."""

from tests.harness.agents import FAST_SIM as FAST_SIM
from tests.harness.agents import AgentProcesses as AgentProcesses
from tests.harness.agents import agent_config as agent_config
