"""What a node reads of the configuration, and nothing else: who it speaks as, where its topics travel,
its ``[security]`` section.

An agent's nodes (MC, HLC, BMA, OSC) take theirs from the agent's config (:meth:`NodeSettings.from_config`)
and keep the whole config for their own logic; a node that flies no vehicle (the operator console, the
scripted operator, a recorder) takes the swarm's buses, topics and key under a name of its own, and is not an
agent in disguise: nothing of an agent's ``[mc]``, ``[hlc]`` or ``[[bma]]`` reaches it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from antalate_lcm.core.config import AgentConfig, Config, SecurityConfig
from antalate_lcm.wire.topics import TopicSpec


@dataclass(frozen=True, slots=True, eq=False)
class NodeSettings:
    """A node's own settings (`Node.__init__`): read by its routes (`core/routes.py`: channels and buses)
    and its admission (`core/admission.py`: keys, window, the replay memory's directory)."""

    #: Who the node speaks as: ``header.agent`` of what it publishes, ``{agent}`` in its channels.
    agent: str
    #: Bus name -> URL (``[buses]``).
    buses: Mapping[str, str]
    #: Every topic the node may name -> its message type and channel template (``[topics]`` applied).
    topics: Mapping[str, TopicSpec]
    #: Topic -> the buses it travels on (published to every one, taken from the first).
    topic_routes: Mapping[str, tuple[str, ...]]
    security: SecurityConfig = field(default_factory=SecurityConfig)

    @classmethod
    def from_config(cls, config: Config, *, agent: str | None = None) -> NodeSettings:
        """The settings of ``config``'s agent's nodes; with ``agent``, of a node that speaks under that
        name on the same swarm (its buses, topics and key): the console, the scripted operator. The name
        is checked as an agent's is (it is part of channel names)."""
        topics = config.topic_specs()
        return cls(
            agent=config.agent.name if agent is None else AgentConfig(name=agent).name,
            buses=dict(config.buses),
            topics=topics,
            topic_routes={topic: tuple(config.topic_buses(topic)) for topic in topics},
            security=config.security,
        )

    def topic_buses(self, topic: str) -> tuple[str, ...]:
        """The buses ``topic`` travels on (the first is the one it is taken from)."""
        try:
            return self.topic_routes[topic]
        except KeyError:
            raise KeyError(f"unknown topic {topic!r}; known: {', '.join(self.topics)}") from None
