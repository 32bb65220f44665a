"""What a range-and-bearing sensor would see of the peers, pure: geometry, limits, noise, dropout.

The paradigm of local, limited sensing of anonymous peers: only peers within ``max_range`` metres
and inside the ``fov`` degrees centred on the heading are seen, each as a range, a bearing relative
to the heading, an elevation and (optionally) a velocity relative to this agent in its body frame,
with Gaussian noise on range and bearing and each detection lost with probability ``dropout``.
Names are left out unless ``identities``; detections come nearest first, so their order says
nothing about who is who. Randomness comes from the ``random.Random`` passed in (seeded: repeatable).
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterable
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.base.geo import body_to_ne, wrap_180


class SensorParams(BaseModel):
    """Validated, since the plugin's ``Params`` are these (one list of names, defaults and bounds for
    the sensor and its config)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    #: m; peers farther away are not seen.
    max_range: float = Field(default=20.0, gt=0, le=1e6, allow_inf_nan=False)
    #: Degrees, the full field of view centred on the heading (360 = all around).
    fov: float = Field(default=360.0, gt=0, le=360, allow_inf_nan=False)
    #: Standard deviations of the noise added to range (m) and bearing (deg); 0 = exact.
    range_noise: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    bearing_noise: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    #: Probability that a peer within range and view is missed in one scan.
    dropout: float = Field(default=0.0, ge=0, le=1, allow_inf_nan=False)
    #: Report each peer's relative velocity (forward, right), else zeros.
    velocity: bool = False
    #: Report each peer's agent name, else "" (anonymous).
    identities: bool = False


@dataclass(frozen=True)
class Body:
    """An agent as the sensor needs it: where (m north/east/up in one frame), how it moves (m/s
    north/east) and which way it faces (deg)."""

    name: str
    north: float
    east: float
    up: float
    vn: float = 0.0
    ve: float = 0.0
    heading: float = 0.0


@dataclass(frozen=True)
class Sighting:
    range: float
    bearing: float
    elevation: float
    rel_forward: float
    rel_right: float
    id: str


def scan(me: Body, others: Iterable[Body], p: SensorParams, rng: random.Random) -> list[Sighting]:
    """The peers ``me`` sees, nearest first."""
    out = []
    for other in others:
        dn, de, du = other.north - me.north, other.east - me.east, other.up - me.up
        horizontal = math.hypot(dn, de)
        rng_true = math.hypot(horizontal, du)
        if rng_true > p.max_range:
            continue
        bearing = wrap_180(math.degrees(math.atan2(de, dn)) - me.heading) if horizontal > 0 else 0.0
        if p.fov < 360.0 and abs(bearing) > p.fov / 2.0:
            continue
        if p.dropout > 0 and rng.random() < p.dropout:
            continue
        if p.velocity:
            # NED -> body is the body-to-NED rotation by -heading (antalate_lcm.base.geo.body_to_ne)
            forward, right = body_to_ne(other.vn - me.vn, other.ve - me.ve, -me.heading)
        else:
            forward = right = 0.0
        measured = max(0.0, rng_true + rng.gauss(0.0, p.range_noise)) if p.range_noise > 0 else rng_true
        if p.bearing_noise > 0:
            bearing = wrap_180(bearing + rng.gauss(0.0, p.bearing_noise))
        elevation = math.degrees(math.atan2(du, horizontal)) if rng_true > 0 else 0.0
        out.append(Sighting(measured, bearing, elevation, forward, right, other.name if p.identities else ""))
    out.sort(key=lambda s: s.range)
    return out
