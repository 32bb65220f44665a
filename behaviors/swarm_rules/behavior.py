"""``gathering``, ``flocking``, ``dispersion``: the canonical swarm rules (``logic.py``) as plugins.

Each reads only the public peer table (``ctx.peers``, ``uses_peers = True``): every other agent's
latest telemetry, heard on the swarm bus in every launch mode. Each publishes an NED
``velocity_cmd_t`` on VELOCITY_CMD at its tick rate (altitude held: vz = 0) while active, and one zero
command on deactivation so the vehicle hovers at once. Until this agent's own position is known
the rules ask for nothing (zero velocity).
"""

from __future__ import annotations

import math
import random
import zlib
from typing import Any

from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.msgs import velocity_cmd_t
from behaviors.swarm_rules.logic import (
    DispersionParams,
    FlockingParams,
    GatheringParams,
    Neighbour,
    Vec,
    dispersion,
    flocking,
    gathering,
)
from behaviors.velocity import velocity_cmd


class _PeerRule(Behavior):
    """The plumbing the three rules share: neighbours from ``ctx.peers``, a velocity out."""

    topics = {"VELOCITY_CMD": velocity_cmd_t}
    activate_on = ("MISSION",)
    tick_hz = 10.0
    uses_peers = True

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.last: Vec = (0.0, 0.0)

    def neighbours(self) -> list[Neighbour] | None:
        """The fresh peers relative to this agent; None until this agent's own position is known."""
        table = self.ctx.peers
        if table.me is None:
            return None
        out = []
        for peer in table.peers(self.ctx.now):
            rel = table.relative(peer)
            if rel is not None:
                out.append(Neighbour(rel[0], rel[1], peer.vn, peer.ve))
        return out

    def on_activate(self) -> None:
        self.log.info("%s with %d peers heard", self.ctx.name, len(self.ctx.peers.peers(self.ctx.now)))

    def tick(self, dt: float) -> None:
        neighbours = self.neighbours()
        self.last = (0.0, 0.0) if neighbours is None else self.rule(neighbours)
        self._publish(*self.last)

    def rule(self, neighbours: list[Neighbour]) -> Vec:
        raise NotImplementedError

    def on_deactivate(self) -> None:
        self.last = (0.0, 0.0)
        self._publish(0.0, 0.0)

    def _publish(self, vn: float, ve: float) -> None:
        self.ctx.publish("VELOCITY_CMD", velocity_cmd(vn, ve))

    def status(self) -> dict[str, Any]:
        """A snapshot for tests and debugging."""
        return {"peers": len(self.ctx.peers.peers(self.ctx.now)), "velocity": self.last}


class Gathering(_PeerRule):
    """Aggregation: towards the centroid of the peers, never nearer than ``separation`` to any."""

    class Params(GatheringParams):
        #: Seed of the jitter; 0 = one fixed by the agent's name (repeatable per agent, different between agents).
        seed: int = 0

    params: Params

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        # The param's seed, else the run's (antalate run --seed), else one fixed by the agent's name.
        self.rng = random.Random(self.params.seed or ctx.seed or zlib.crc32(ctx.agent.encode()))

    def rule(self, neighbours: list[Neighbour]) -> Vec:
        angle = self.rng.uniform(0.0, 2.0 * math.pi)
        return gathering(neighbours, self.params, (math.cos(angle), math.sin(angle)))


class Flocking(_PeerRule):
    """Reynolds/Vicsek flocking: separation, alignment, cohesion at a cruise speed."""

    class Params(FlockingParams):
        """``heading`` omitted: one fixed by the agent's name, so the flock starts in disorder and
        alignment has to agree on one."""

    params: Params

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.rule_params = self.params
        if "heading" not in self.params.model_fields_set:
            self.rule_params = self.params.model_copy(
                update={"heading": float(zlib.crc32(ctx.agent.encode()) % 360)}
            )

    def rule(self, neighbours: list[Neighbour]) -> Vec:
        me = self.ctx.peers.me
        own = (me.vn, me.ve) if me is not None else (0.0, 0.0)
        return flocking(own, neighbours, self.rule_params)


class Dispersion(_PeerRule):
    """Area coverage: spread to ``spacing`` from every peer, within ``area_radius`` of the takeoff point."""

    Params = DispersionParams
    params: DispersionParams

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        #: (north, east) of the first position this behavior saw, in the table's frame.
        self.home: tuple[float, float] | None = None

    def rule(self, neighbours: list[Neighbour]) -> Vec:
        me = self.ctx.peers.me
        if me is None:
            return 0.0, 0.0
        if self.home is None:
            self.home = (me.north, me.east)
        return dispersion((self.home[0] - me.north, self.home[1] - me.east), neighbours, self.params)
