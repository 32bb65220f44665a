"""The peer table: every other agent's latest position, velocity, heading and MC state, pure.

One table is what a swarm needs from its members' own telemetry, and several consumers need it: the
BMA hands one to every behavior (``ctx.peers``, docs/behaviors.md), the HLC's collision filter reads
the same one. So it is a small pure module with no I/O and no clock of its own: whoever subscribes
feeds it (:meth:`PeerTable.update_telemetry`, :meth:`PeerTable.update_state`) and passes the time in.

Frames (docs/behaviors.md, "Peers"):

* WGS84: ``lat``/``lon`` as the peer published them (``telemetry_t``).
* Local north/east/up in metres, relative to the table's **origin**: the point given at construction,
  else the first position the table is fed (normally its own agent's, which an agent's HLC publishes
  from the start). North/east are the :class:`~antalate_lcm.base.geo.FlatFrame` tangent plane at the
  origin (centimetres off the exact geodesic within 1 km); ``up`` is the peer's ``alt``, metres above
  *its own* home, so heights compare across agents only over a flat field. Relative quantities
  (:meth:`PeerTable.relative`, a centroid minus :attr:`PeerTable.me`) do not depend on the origin.

Ages are on the feeder's monotonic clock (``now`` arguments), not the sender's: a peer whose clock is
off still ages correctly. A peer not heard for ``stale_after`` s is stale (left out of
:meth:`PeerTable.peers` and :meth:`PeerTable.centroid`, listed by :meth:`PeerTable.stale`); one not
heard for ``forget_after`` s is dropped, so the table is bounded by who spoke recently (and by
``max_peers``: channel names come from the network).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

from antalate_lcm.base.geo import FlatFrame, wrap_360
from antalate_lcm.msgs import telemetry_t
from antalate_lcm.wire.vocabulary import McState, name_of

#: s without telemetry after which a peer is stale (ten missed 10 Hz telemetry messages).
DEFAULT_STALE_AFTER = 1.0
#: s without telemetry after which a peer is forgotten.
DEFAULT_FORGET_AFTER = 30.0
#: Most agents a table holds (a flood of made-up names must not grow it without bound).
DEFAULT_MAX_PEERS = 10_000


@dataclass(frozen=True)
class Peer:
    """One agent's latest telemetry, in WGS84 and in the table's local frame.

    ``received`` is when the table was fed it (the feeder's monotonic clock), ``utime`` the sender's
    header time (µs since the epoch, its clock). ``mc_state`` is the agent's last Mission Control
    state name (``"MISSION"``), None until one is heard.
    """

    agent: str
    lat: float
    lon: float
    #: m above the agent's own home (takeoff point).
    alt: float
    #: m north / east of the table's origin; ``up`` = ``alt``.
    north: float
    east: float
    #: m/s, north / east / down (NED), as telemetry_t.
    vn: float
    ve: float
    vd: float
    #: Degrees clockwise from north, [0, 360).
    heading: float
    armed: bool
    in_air: bool
    mc_state: str | None
    utime: int
    received: float

    @property
    def up(self) -> float:
        return self.alt

    @property
    def position(self) -> tuple[float, float, float]:
        """(north, east, up) in metres in the table's frame."""
        return self.north, self.east, self.alt

    @property
    def velocity(self) -> tuple[float, float, float]:
        """(north, east, up) in m/s: ``up`` = -``vd``, so position and velocity share one frame."""
        return self.vn, self.ve, -self.vd

    @property
    def speed(self) -> float:
        """Horizontal ground speed, m/s."""
        return math.hypot(self.vn, self.ve)

    def age(self, now: float) -> float:
        """Seconds since the table was fed this record (``now`` on the feeder's clock)."""
        return now - self.received


class PeerTable:
    """The latest record of every agent heard, split into this agent (:attr:`me`) and its peers.

    Not thread-safe, like everything fed on the executor thread. Every query takes ``now`` (the
    feeder's monotonic clock) so the table needs none of its own and tests need no sleeps.
    """

    def __init__(
        self,
        agent: str,
        *,
        origin: tuple[float, float] | None = None,
        stale_after: float = DEFAULT_STALE_AFTER,
        forget_after: float = DEFAULT_FORGET_AFTER,
        max_peers: int = DEFAULT_MAX_PEERS,
    ) -> None:
        if not (math.isfinite(stale_after) and stale_after > 0):
            raise ValueError(f"stale_after must be a positive number of seconds, got {stale_after!r}")
        if not (math.isfinite(forget_after) and forget_after >= stale_after):
            raise ValueError(
                f"forget_after must be at least stale_after ({stale_after}), got {forget_after!r}"
            )
        if max_peers < 1:
            raise ValueError(f"max_peers must be at least 1, got {max_peers!r}")
        self.agent = agent
        self.stale_after = stale_after
        self.forget_after = forget_after
        self.max_peers = max_peers
        self._frame: FlatFrame | None = None
        if origin is not None:
            self._frame = _frame(*origin)
        self._me: Peer | None = None
        self._peers: dict[str, Peer] = {}
        #: MC states heard before any telemetry of that agent (kept until its telemetry comes).
        self._states: dict[str, str] = {}
        #: Telemetry messages refused: non-finite values or older than the record held.
        self.rejected = 0

    # ------------------------------------------------------------------ feeding
    @property
    def origin(self) -> tuple[float, float] | None:
        """(lat, lon) of the local frame's origin; None until set or fed a first position."""
        frame = self._frame
        return None if frame is None else (frame.lat0, frame.lon0)

    def update_telemetry(self, agent: str, msg: telemetry_t, now: float) -> bool:
        """Record ``agent``'s telemetry; False (and counted in :attr:`rejected`) when it is refused:
        a non-finite position, velocity or heading, or a message no newer (``header.utime``) than the
        one held (a datagram that arrived late or twice)."""
        values = (msg.lat, msg.lon, msg.alt, msg.heading, msg.vn, msg.ve, msg.vd)
        if not all(math.isfinite(v) for v in values) or not (-90.0 <= msg.lat <= 90.0):
            self.rejected += 1
            return False
        held = self._me if agent == self.agent else self._peers.get(agent)
        if held is not None and msg.header.utime <= held.utime:
            self.rejected += 1
            return False
        if held is None and agent != self.agent and len(self._peers) >= self.max_peers:
            self.forget(now)
            if len(self._peers) >= self.max_peers:
                self.rejected += 1
                return False
        frame = self._frame
        if frame is None:
            frame = self._frame = _frame(msg.lat, msg.lon)
        north, east = frame.to_ne(msg.lat, msg.lon)
        state = held.mc_state if held is not None else self._states.pop(agent, None)
        record = Peer(
            agent=agent,
            lat=float(msg.lat),
            lon=float(msg.lon),
            alt=float(msg.alt),
            north=north,
            east=east,
            vn=float(msg.vn),
            ve=float(msg.ve),
            vd=float(msg.vd),
            heading=wrap_360(float(msg.heading)),
            armed=bool(msg.armed),
            in_air=bool(msg.in_air),
            mc_state=state,
            utime=int(msg.header.utime),
            received=now,
        )
        if agent == self.agent:
            self._me = record
        else:
            self._peers[agent] = record
        return True

    def update_state(self, agent: str, state: int | str, now: float) -> bool:
        """Record ``agent``'s Mission Control state (an ``mc_state_t.state`` value or its name);
        False for a value the contract does not define. It does not refresh the record's age: only
        telemetry says where a peer is."""
        name = name_of(McState, state) if isinstance(state, int) else state
        if name is None or name not in McState.__members__:
            return False
        held = self._me if agent == self.agent else self._peers.get(agent)
        if held is None:
            if agent != self.agent and len(self._states) >= self.max_peers:
                return False
            self._states[agent] = name
        elif agent == self.agent:
            self._me = replace(held, mc_state=name)
        else:
            self._peers[agent] = replace(held, mc_state=name)
        return True

    def forget(self, now: float) -> list[str]:
        """Drop the peers not heard for ``forget_after`` s; returns their names."""
        gone = [a for a, p in self._peers.items() if now - p.received > self.forget_after]
        for agent in gone:
            del self._peers[agent]
        return gone

    # ------------------------------------------------------------------ reading
    @property
    def me(self) -> Peer | None:
        """This agent's own latest record (None until its telemetry is fed)."""
        return self._me

    def get(self, agent: str) -> Peer | None:
        """A peer's latest record, stale or not (None if unknown)."""
        return self._peers.get(agent)

    def peers(self, now: float, *, max_age: float | None = None) -> list[Peer]:
        """The peers heard within ``max_age`` s (default ``stale_after``), by name; never this agent."""
        limit = self.stale_after if max_age is None else max_age
        return [p for _, p in sorted(self._peers.items()) if now - p.received <= limit]

    def stale(self, now: float) -> list[Peer]:
        """The peers known but not heard for ``stale_after`` s (not yet forgotten), by name."""
        return [p for _, p in sorted(self._peers.items()) if now - p.received > self.stale_after]

    def relative(self, peer: Peer) -> tuple[float, float, float] | None:
        """(north, east, up) metres from this agent to ``peer``; None until this agent's own
        position is known."""
        me = self._me
        if me is None:
            return None
        return peer.north - me.north, peer.east - me.east, peer.alt - me.alt

    def centroid(self, now: float, *, include_self: bool = False) -> tuple[float, float, float] | None:
        """The mean (north, east, up) of the fresh peers (and this agent with ``include_self``);
        None when there is none."""
        members = self.peers(now)
        if include_self and self._me is not None:
            members.append(self._me)
        if not members:
            return None
        n = len(members)
        return (
            sum(p.north for p in members) / n,
            sum(p.east for p in members) / n,
            sum(p.alt for p in members) / n,
        )

    def __len__(self) -> int:
        """Peers known (stale ones included, this agent not)."""
        return len(self._peers)

    def __contains__(self, agent: object) -> bool:
        return agent in self._peers

    def __iter__(self) -> Iterator[Peer]:
        """Every known peer, stale ones included, by name."""
        return iter([p for _, p in sorted(self._peers.items())])


def _frame(lat: float, lon: float) -> FlatFrame:
    if not (math.isfinite(lat) and math.isfinite(lon) and -90.0 <= lat <= 90.0):
        raise ValueError(f"origin must be a finite WGS84 (lat, lon), got ({lat!r}, {lon!r})")
    return FlatFrame(lat, lon)


__all__ = ["DEFAULT_FORGET_AFTER", "DEFAULT_MAX_PEERS", "DEFAULT_STALE_AFTER", "Peer", "PeerTable"]
