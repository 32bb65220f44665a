"""Where a node's topics travel: each topic's channel, bus(es) and destination, from its settings and context.

The node's settings (:class:`~antalate_lcm.core.node_settings.NodeSettings`, from the config) name each
topic's buses and channel template, so moving a node to another machine is a config change; an agent's
internal topics also travel on the context's in-process bus
(:meth:`~antalate_lcm.core.context.Context.in_process`), so its own nodes never take them from the
network. :class:`~antalate_lcm.core.node.Node` holds one :class:`Routes`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from antalate_lcm.core.bus_connection import Lane
from antalate_lcm.core.context import Context
from antalate_lcm.core.node_settings import NodeSettings
from antalate_lcm.wire.topics import TopicSpec, is_internal


@dataclass(frozen=True, slots=True)
class Destination:
    """Where one topic's messages (its channel with given template fields) are sent."""

    buses: list[str]
    channel: str
    #: The send function (`Buses.sender`) of each bus but the lane's, resolved once: 20 publishes a
    #: second per agent.
    senders: list[tuple[str, Callable[[str, bytes], None]]]
    #: The channel's lane when the first bus is memq:// (`Buses.lane`: no lookup per message).
    lane: Lane | None = None


class Routes:
    """A node's topics: their channels, the buses each is published to and taken from."""

    def __init__(self, settings: NodeSettings, context: Context) -> None:
        self.settings = settings
        self.context = context
        self.agent = settings.agent
        self.specs = settings.topics

    def spec(self, topic: str) -> TopicSpec:
        try:
            return self.specs[topic]
        except KeyError:
            raise KeyError(f"unknown topic {topic!r}; known: {', '.join(self.specs)}") from None

    def channel(self, topic: str, **fields: str) -> str:
        return self.spec(topic).channel.format(**{"agent": self.agent, **fields})

    def destination(self, topic: str, fields: dict[str, str]) -> Destination:
        """Where the topic (its channel with ``fields``) is sent: its first bus's lane if that is
        memq:// (an agent's in-process bus, where an internal topic goes first), and the send
        functions of the rest, shared by the context's publishers on the same buses."""
        channel = self.channel(topic, **fields)
        buses = self.publish_buses(topic)
        bus = self.context.buses
        lane = bus.lane(buses[0], channel) if buses else None
        rest = tuple(buses[1:] if lane is not None else buses)
        shared = self.context.senders
        senders = shared.get(rest)
        if senders is None:
            senders = shared[rest] = [(name, bus.sender(name)) for name in rest]
        return Destination(buses, channel, senders, lane)

    def publish_buses(self, topic: str) -> list[str]:
        """The topic's buses (plus the in-process bus for an internal topic), one per distinct URL."""
        names = self.settings.topic_buses(topic)
        inproc = self.context.inproc_bus
        if inproc is not None and is_internal(topic):
            names = (inproc, *names)
        out: list[str] = []
        seen: set[str] = set()
        for name in names:
            url = self.context.buses.urls.get(name, name)
            if url not in seen:  # two names for one URL are one LCM instance: send once
                seen.add(url)
                out.append(name)
        return out

    def subscribe_bus(self, topic: str) -> str:
        """The bus a topic is taken from: the in-process one for an internal topic when there is
        one, else the topic's first configured bus."""
        inproc = self.context.inproc_bus
        if inproc is not None and is_internal(topic):
            return inproc
        return self.settings.topic_buses(topic)[0]
