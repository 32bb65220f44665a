"""Zenoh election groups: who is alive in a group, from Zenoh liveliness tokens (the bridges of a
site elect the one that forwards to their LAN: docs/wan.md), signed with the swarm key when there is one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol


class GroupProof(Protocol):
    """Signs and checks election tokens (:class:`antalate_lcm.wire.security.MemberProof`, with the swarm key);
    a protocol here so the transport does not depend on the security module that asks it."""

    @property
    def refresh(self) -> float: ...

    def token(self, group: str, member: str, now: float) -> str: ...

    def check(self, group: str, name: str, now: float) -> tuple[str, float] | str: ...

    def fresh(self, t: float, now: float) -> bool: ...


@dataclass(eq=False)
class _Group:
    """Who is in one group: the live token names of each member (pure; the clock is passed)."""

    key: str
    group: str
    member: str
    on_change: Callable[[frozenset[str]], None]
    proof: GroupProof | None = None
    #: member -> {token name: the time it proves (0 without a proof)}
    tokens: dict[str, dict[str, float]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    report_lock: threading.Lock = field(default_factory=threading.Lock)
    reported: frozenset[str] | None = None
    token: Any = None
    sub: Any = None

    def seen(self, name: str, alive: bool, now: float) -> str | None:
        """A token appeared or went away; why it does not count, or None."""
        if self.proof is None:
            who, t = name, 0.0
        else:
            checked = self.proof.check(self.group, name, now)
            if isinstance(checked, str):
                return None if not alive else checked  # a forged token going away changes nothing
            who, t = checked
        with self.lock:
            if alive:
                self.tokens.setdefault(who, {})[name] = t
            else:
                mine = self.tokens.get(who, {})
                mine.pop(name, None)
                if not mine:
                    self.tokens.pop(who, None)
        return None

    def expire(self, now: float) -> None:
        if self.proof is None:
            return
        with self.lock:
            for who in list(self.tokens):
                fresh = {n: t for n, t in self.tokens[who].items() if self.proof.fresh(t, now)}
                if fresh:
                    self.tokens[who] = fresh
                else:
                    del self.tokens[who]

    def members(self) -> frozenset[str]:
        with self.lock:
            return frozenset(self.tokens) | {self.member}

    def report(self) -> None:
        """Tell ``on_change`` the members if they changed (in order: Zenoh's and the refresher's threads)."""
        with self.report_lock:
            members = self.members()
            if members != self.reported:
                self.reported = members
                self.on_change(members)
