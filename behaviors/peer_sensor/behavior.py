"""``peer_sensor``: publishes ``peer_scan_t`` on PEER_SCAN, computed from the peers' telemetry.

A behavior written against PEER_SCAN flies unchanged on a real vehicle, where the same topic comes
from a real sensor's behavior or the station's geodesic sensing: only the config changes (this
plugin out, the other in). Active by default for the whole flight, so a consumer's first tick in
MISSION already has a scan.
"""

from __future__ import annotations

import random

from antalate_lcm.core.behavior import Behavior, BehaviorContext
from antalate_lcm.msgs import peer_scan_t
from antalate_lcm.wire.peers import Peer
from behaviors.peer_sensor.logic import Body, SensorParams, scan


def _body(peer: Peer) -> Body:
    return Body(peer.agent, peer.north, peer.east, peer.up, peer.vn, peer.ve, peer.heading)


class PeerSensor(Behavior):
    """The simulated range-and-bearing sensor of peers (``logic.scan``)."""

    class Params(SensorParams):
        #: Seed of the noise and dropout; 0 = the run's (`antalate run --seed`), else a different one every run.
        seed: int = 0

    params: Params
    topics = {"PEER_SCAN": peer_scan_t}
    activate_on = ("TAKEOFF", "MISSION", "RTL", "LAND", "HOLD")
    tick_hz = 10.0
    uses_peers = True

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        # The param's seed, else the run's (antalate run --seed), else a fresh one each run.
        self.rng = random.Random(self.params.seed or ctx.seed)

    def on_activate(self) -> None:
        self.log.info(
            "sensing peers within %g m, %g deg field of view", self.params.max_range, self.params.fov
        )

    def tick(self, dt: float) -> None:
        table = self.ctx.peers
        me = table.me
        if me is None:  # this agent's own position is not known yet: nothing to measure from
            return
        sightings = scan(_body(me), (_body(p) for p in table.peers(self.ctx.now)), self.params, self.rng)
        msg = peer_scan_t()
        msg.max_range, msg.fov, msg.has_velocity = (
            self.params.max_range,
            self.params.fov,
            self.params.velocity,
        )
        msg.n = len(sightings)
        msg.range = [s.range for s in sightings]
        msg.bearing = [s.bearing for s in sightings]
        msg.elevation = [s.elevation for s in sightings]
        msg.rel_forward = [s.rel_forward for s in sightings]
        msg.rel_right = [s.rel_right for s in sightings]
        msg.id = [s.id for s in sightings]
        self.ctx.publish("PEER_SCAN", msg)
