"""A subscription to one bus (:meth:`~antalate_lcm.core.bus.Buses.subscribe`) and the subscribers of
one exact channel as a :class:`~antalate_lcm.core.bus_connection.BusConnection` keeps them for its loop."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from antalate_lcm.wire.fastcodec import decoder
from antalate_lcm.wire.topics import Message

Handler = Callable[[str, Any], None]


@dataclass(eq=False, slots=True)
class Subscription:
    """A handle returned by :meth:`Buses.subscribe`; pass it to :meth:`Buses.unsubscribe`.

    Slotted: every delivery reads its ``active`` and ``handler`` (5 per agent, a thousand agents)."""

    bus: str
    channel: str
    msg_type: type[Message] | None
    #: ``handler(channel, msg)``, or ``handler(msg)`` with ``msg_only`` (an exact channel's: a node's
    #: handler called by the bus itself, no closure in between on every message).
    handler: Callable[..., None]
    regex: re.Pattern[str] | None = None
    active: bool = field(default=True)
    msg_only: bool = False
    #: ``msg_type``'s decoder (antalate_lcm.wire.fastcodec: lcm-gen's fields, a third of its time).
    decode: Callable[[bytes], Any] | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.msg_type is not None:
            self.decode = decoder(self.msg_type)


#: Characters with a meaning in LCM's channel regular expressions.
_REGEX_SPECIAL = re.compile(r"([.^$*+?()\[\]{}|\\])")


def lcm_literal(channel: str) -> str:
    """An LCM channel regex matching exactly ``channel``."""
    return _REGEX_SPECIAL.sub(r"\\\1", channel)


class Route:
    """The subscribers of one exact channel and the LCM subscription that feeds them."""

    __slots__ = ("subs", "decode", "mixed", "lcm_sub", "retired")

    def __init__(self) -> None:
        #: The loop's snapshot: replaced, never mutated, so a handler may unsubscribe mid-delivery.
        self.subs: tuple[Subscription, ...] = ()
        #: The subscribers' one decoder (one subscriber, or several of one type), else None.
        self.decode: Callable[[bytes], Any] | None = None
        #: Subscribers of more than one type (or raw beside typed): `_deliver` decodes per type.
        self.mixed = False
        self.lcm_sub: Any = None
        self.retired = False

    def add(self, sub: Subscription) -> None:
        """Under the lock; no pass over the others in Python (every agent subscribes to
        SWARM/OPERATOR_CMD: a set of their types each time made a 1,000-agent start quadratic)."""
        subs = self.subs
        if subs and sub.msg_type is not subs[0].msg_type:
            self.mixed = True
        self.decode = None if self.mixed else (subs[0] if subs else sub).decode
        self.subs = (*subs, sub)

    def discard(self, sub: Subscription) -> None:
        """Under the lock: ``sub`` leaves (if here); nodes stop in the reverse of their start."""
        subs = self.subs
        if subs and subs[-1] is sub:
            rest = subs[:-1]
        else:
            try:
                i = subs.index(sub)  # identity: Subscription has no __eq__ of its own
            except ValueError:
                return
            rest = subs[:i] + subs[i + 1 :]
        if self.mixed:  # rare (a raw subscriber beside typed ones): look again
            self.mixed = any(s.msg_type is not rest[0].msg_type for s in rest)
        self.decode = None if self.mixed or not rest else rest[0].decode
        self.subs = rest


__all__ = ["Handler", "Route", "Subscription", "lcm_literal"]
