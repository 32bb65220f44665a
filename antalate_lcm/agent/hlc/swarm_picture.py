"""Where every agent is, once per process, indexed by place: what each HLC's safety filter asks.

A thousand agents in one process (``antalate agent --agents 1000``) each needing every other agent's
position would cost a thousand tables fed ten thousand telemetry messages a second: a million updates
a second, which no Python process does. So the agents of a process share one `SwarmPicture`: one
`antalate_lcm.wire.peers.PeerTable` (the same table behaviors get, here holding every agent: its own
name is "", which no agent has), fed once per message, plus a grid of square cells so that a filter
asks only for the agents near it. Pure: the node subscribes and feeds it.

The grid only holds fresh agents (heard within ``stale_after``); stale ones -- whose uncertainty balls
grow and may reach far -- are listed apart and handed to every query, so a silent agent is never
missed. The lists are refreshed by `SwarmPicture.sweep`, which the node calls a few times a second.
"""

from __future__ import annotations

import math

from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.msgs import telemetry_t
from antalate_lcm.wire.peers import Peer, PeerTable

Cell = tuple[int, int]


class SwarmPicture:
    """Every agent heard (fresh ones in a grid of `cell` metres), in one local frame."""

    def __init__(
        self,
        *,
        cell: float,
        stale_after: float,
        forget_after: float,
        origin: tuple[float, float] | None = None,
    ) -> None:
        if not (math.isfinite(cell) and cell > 0.0):
            raise ValueError(f"SwarmPicture cell must be > 0 m, got {cell!r}")
        self.cell = cell
        self._stale_after = stale_after
        self._forget_after = forget_after
        self.table: PeerTable | None = None
        self.frame: FlatFrame | None = None
        self._grid: dict[Cell, set[str]] = {}
        self._where: dict[str, Cell] = {}  # agent -> its cell
        self._stale: list[Peer] = []
        if origin is not None:
            self.place(*origin)

    def place(self, lat: float, lon: float) -> FlatFrame:
        """The local frame, fixed at (lat, lon) if it is not yet (the first position fed or asked)."""
        if self.frame is None:
            self.table = PeerTable(
                "",
                origin=(lat, lon),
                stale_after=self._stale_after,
                forget_after=self._forget_after,
            )
            self.frame = FlatFrame(lat, lon)
        return self.frame

    # ------------------------------------------------------------------ feeding
    def feed(self, agent: str, msg: telemetry_t, now: float) -> bool:
        """An agent's telemetry; False when the table refuses it (non-finite, repeated, too many)."""
        if not agent:
            return False
        if self.table is None:
            if not (math.isfinite(msg.lat) and math.isfinite(msg.lon) and -90.0 <= msg.lat <= 90.0):
                return False
            self.place(msg.lat, msg.lon)
        table = self.table
        assert table is not None
        if not table.update_telemetry(agent, msg, now):
            return False
        peer = table.get(agent)
        assert peer is not None
        if self._stale:  # heard again: back in the grid, off the stale list
            self._stale = [p for p in self._stale if p.agent != agent]
        cell = (math.floor(peer.north / self.cell), math.floor(peer.east / self.cell))
        old = self._where.get(agent)
        if old != cell:
            if old is not None:
                self._grid[old].discard(agent)
            self._grid.setdefault(cell, set()).add(agent)
            self._where[agent] = cell
        return True

    def state(self, agent: str, state: int, now: float) -> None:
        if self.table is not None and agent:
            self.table.update_state(agent, state, now)

    def sweep(self, now: float) -> None:
        """Forget the agents silent for ``forget_after``; move the stale ones out of the grid."""
        table = self.table
        if table is None:
            return
        for agent in table.forget(now):
            self._drop(agent)
        self._stale = table.stale(now)
        for peer in self._stale:
            self._drop(peer.agent)

    def _drop(self, agent: str) -> None:
        cell = self._where.pop(agent, None)
        if cell is not None:
            members = self._grid[cell]
            members.discard(agent)
            if not members:
                del self._grid[cell]

    # ------------------------------------------------------------------ reading
    def near(self, me: str, north: float, east: float, reach: float) -> list[Peer]:
        """The agents other than `me` in the cells within `reach` metres of (north, east), and every
        stale one (a superset: the filter measures the real distances)."""
        table = self.table
        if table is None:
            return []
        out = [p for p in self._stale if p.agent != me]
        k = math.ceil(reach / self.cell)
        cn, ce = math.floor(north / self.cell), math.floor(east / self.cell)
        grid = self._grid
        get = table.get
        for i in range(cn - k, cn + k + 1):
            for j in range(ce - k, ce + k + 1):
                members = grid.get((i, j))
                if not members:
                    continue
                for agent in members:
                    if agent != me:
                        peer = get(agent)
                        if peer is not None:
                            out.append(peer)
        return out

    def fresh(self, me: str) -> int:
        """How many agents other than `me` were fresh at the last sweep (for ``min_peers``)."""
        table = self.table
        if table is None:
            return 0
        return len(self._where) - (1 if me in self._where else 0)

    def __len__(self) -> int:
        return 0 if self.table is None else len(self.table)
