"""What a log says about the swarm's safety (docs/safety.md): separation over the whole flight,
near-misses, fence breaches, the HLCs' SAFETY reports, and whether the mission still flew (pure).

Definitions (``antalate analyze --radius R``, or ``--safety CONFIG`` for the radius, half-height and
fence of an agent config's ``[safety]``):

* **In the air**: an agent whose latest telemetry says ``in_air`` (agents on the ground, parked side
  by side, are not a loss of separation).
* **Separation** of two agents at t: their distance at their positions interpolated to t, with the
  vertical axis stretched by ``radius / vertical`` (the filter's ellipsoid: ``vertical`` m above or
  below is as far as ``radius`` m beside); without ``vertical``, the 3-D distance. The 3-D distance
  of the closest pair is given beside it.
* **Minimum separation**: the smallest separation of any two agents in the air, sampled every ``step``
  s over the whole log (every phase: take-off, mission, return and landing).
* **Near-miss**: an encounter of one pair closer than ``near_miss`` m (the radius by default): the
  consecutive samples it lasts, its closest distance and when. A near-miss closer than the radius
  minus the documented ``margin`` is a **loss of separation**.
* **Fence breach**: an agent in the air outside the fence's polygon, above its ceiling or below its
  floor (margins not counted), the consecutive samples it lasts being one breach.
* **Mission flown**: the agents whose MC reached MISSION, those that were back in STANDBY on the
  ground at the end of the log.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

from antalate_lcm.apps.analysis.records import SafetyEvent, SwarmRecord
from antalate_lcm.apps.analysis.swarm import sample_times
from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.base.safety.geofence import Geofence

#: Agents below this height (m) are taking off or landing on their own spot: a fence floor does not apply.
GROUND_HEIGHT = 1.0


@dataclass(frozen=True)
class SafetyLimits:
    """What the log is checked against (the swarm's ``[safety]`` config)."""

    radius: float
    #: m, the ellipsoid's half-height; None: separation is the plain 3-D distance.
    vertical: float | None = None
    #: m below the radius still within the documented margin (docs/safety.md).
    margin: float = 0.0
    #: m: encounters closer than this are near-misses (default: the radius).
    near_miss: float | None = None
    #: The fence in the frame of `origin`, if any.
    fence: Geofence | None = None
    #: [lat, lon] of the fence's local frame (the config's [safety] origin); None: the first fix's mean.
    origin: tuple[float, float] | None = None

    @property
    def threshold(self) -> float:
        return self.near_miss if self.near_miss is not None else self.radius


@dataclass(frozen=True)
class Encounter:
    """A near-miss (two agents) or a fence breach (one agent, ``b`` empty)."""

    a: str
    b: str
    start: float
    end: float
    #: The closest separation (near-miss) or the farthest excursion's description (breach).
    distance: float
    t: float
    what: str = ""


@dataclass
class SafetyAnalysis:
    limits: SafetyLimits
    samples: int = 0
    min_separation: float | None = None
    min_separation_3d: float | None = None
    min_t: float | None = None
    min_pair: tuple[str, str] | None = None
    near_misses: list[Encounter] = field(default_factory=list)
    breaches: list[Encounter] = field(default_factory=list)
    #: SAFETY reports by kind: "separation", "fence", "fence+separation" (who modified a command),
    #: "conflict" (a constraint it could not keep), "outside fence", "no peers", "fence mirror", "other".
    events_by_kind: dict[str, int] = field(default_factory=dict)
    events_by_agent: dict[str, int] = field(default_factory=dict)
    #: A few reports as logged (the first of each kind).
    examples: list[SafetyEvent] = field(default_factory=list)
    agents: int = 0
    flew_mission: list[str] = field(default_factory=list)
    landed: list[str] = field(default_factory=list)

    @property
    def losses(self) -> list[Encounter]:
        """The near-misses closer than the radius minus the margin."""
        floor = self.limits.radius - self.limits.margin
        return [e for e in self.near_misses if e.distance < floor]


def event_kind(text: str) -> str:
    """The kind of a SAFETY report, from its text (antalate_lcm.agent.hlc.safety.describe and the fence mirror)."""
    if "fence mirrored" in text or "does not hold the fence" in text:
        return "fence mirror"
    if "no peer information" in text:
        return "no peers"
    if "cannot keep" in text:
        return "conflict"
    if any(f"{where} the fence" in text for where in ("outside", "above", "below")):
        return "outside fence"
    if "modified by" in text:
        return text.split("modified by ", 1)[1].split(";", 1)[0].strip()
    return "other"


class _Positions:
    """One agent's telemetry in the local frame, interpolated like `Track.position_at` (3-D)."""

    def __init__(
        self, t: list[float], ne: list[tuple[float, float]], alt: list[float], air: list[bool]
    ) -> None:
        self.t, self.ne, self.alt, self.air = t, ne, alt, air

    def at(self, t: float, max_age: float) -> tuple[float, float, float] | None:
        """(north, east, up) at `t` while the agent is in the air and heard; None otherwise."""
        i = bisect.bisect_right(self.t, t)
        if i == 0:
            return None
        t0 = self.t[i - 1]
        if t - t0 > max_age or not self.air[i - 1]:
            return None
        (n, e), u = self.ne[i - 1], self.alt[i - 1]
        if i < len(self.t) and self.t[i] > t0 and self.t[i] - t0 <= max_age:
            f = (t - t0) / (self.t[i] - t0)
            (n1, e1), u1 = self.ne[i], self.alt[i]
            n, e, u = n + f * (n1 - n), e + f * (e1 - e), u + f * (u1 - u)
        return n, e, u


def _positions(record: SwarmRecord, origin: tuple[float, float]) -> dict[str, _Positions]:
    frame = FlatFrame(*origin)
    out = {}
    for name, rec in sorted(record.agents.items()):
        samples = sorted(
            (s for s in rec.telemetry if math.isfinite(s.lat) and math.isfinite(s.lon)), key=lambda s: s.t
        )
        if samples:
            out[name] = _Positions(
                [s.t for s in samples],
                [frame.to_ne(s.lat, s.lon) for s in samples],
                [s.alt for s in samples],
                [s.in_air for s in samples],
            )
    return out


def _close_pairs(
    where: dict[str, tuple[float, float, float]], stretch: float, reach: float
) -> list[tuple[float, float, str, str]]:
    """(separation, 3-D distance, a, b) of every pair in neighbouring cells of a `reach`-wide grid:
    every pair closer than `reach`, and some farther."""
    cells: dict[tuple[int, int], list[str]] = {}
    for name, (n, e, _) in where.items():
        key = (0, 0) if math.isinf(reach) else (math.floor(n / reach), math.floor(e / reach))
        cells.setdefault(key, []).append(name)
    out = []
    for (ci, cj), names in cells.items():
        near = [m for di in (-1, 0, 1) for dj in (-1, 0, 1) for m in cells.get((ci + di, cj + dj), ())]
        for a in names:
            pa = where[a]
            for b in near:
                if b <= a:
                    continue
                pb = where[b]
                dn, de, du = pa[0] - pb[0], pa[1] - pb[1], pa[2] - pb[2]
                d = math.sqrt(dn * dn + de * de + (du * stretch) ** 2)
                out.append((d, math.sqrt(dn * dn + de * de + du * du), a, b))
    return out


def analyze_safety(
    record: SwarmRecord,
    limits: SafetyLimits,
    origin: tuple[float, float],
    *,
    step: float = 0.1,
    max_age: float = 2.0,
) -> SafetyAnalysis:
    """Every figure of the module docstring; `origin` is the analysis frame's (used without `limits.origin`)."""
    result = SafetyAnalysis(limits)
    frame_origin = limits.origin or origin
    positions = _positions(record, frame_origin)
    result.agents = len(positions)
    stretch = limits.radius / limits.vertical if limits.vertical else 1.0
    threshold = limits.threshold
    # Pairs farther apart horizontally than this are neither close nor near-misses; a sample whose
    # closest pair is farther is searched whole (below), so the minimum is always exact.
    reach = max(threshold, limits.radius) * 4.0
    open_pairs: dict[tuple[str, str], list[float]] = {}  # pair -> [start, end, closest, when]
    open_out: dict[str, list[float | str]] = {}
    last_t = 0.0
    if positions:
        start = min(p.t[0] for p in positions.values())
        end = max(p.t[-1] for p in positions.values())
        for t in sample_times(start, end, step):
            last_t = t
            where = {}
            for name, p in positions.items():
                at = p.at(t, max_age)
                if at is not None:
                    where[name] = at
            result.samples += 1
            pairs = _close_pairs(where, stretch, reach)
            if len(where) > 1 and min((p[0] for p in pairs), default=math.inf) >= reach:
                pairs = _close_pairs(where, stretch, math.inf)
            close = set()
            for d, d3, a, b in pairs:
                if result.min_separation is None or d < result.min_separation:
                    result.min_separation, result.min_separation_3d = d, d3
                    result.min_t, result.min_pair = t, (a, b)
                if d < threshold:
                    close.add((a, b))
                    enc = open_pairs.get((a, b))
                    if enc is None:
                        open_pairs[(a, b)] = [t, t, d, t]
                    else:
                        enc[1] = t
                        if d < enc[2]:
                            enc[2], enc[3] = d, t
            for pair in [p for p in open_pairs if p not in close]:
                s, e, d, when = open_pairs.pop(pair)
                result.near_misses.append(Encounter(pair[0], pair[1], s, e, d, when))
            if limits.fence is not None:
                _fence_samples(limits.fence, where, t, open_out, result)
    for pair, (s, e, d, when) in open_pairs.items():
        result.near_misses.append(Encounter(pair[0], pair[1], s, e, d, when))
    for agent in list(open_out):
        _close_breach(agent, open_out, result, last_t)
    result.near_misses.sort(key=lambda x: (x.distance, x.t))
    result.breaches.sort(key=lambda x: x.start)
    for ev in record.safety_events:
        kind = event_kind(ev.text)
        if kind not in result.events_by_kind:
            result.examples.append(ev)
        result.events_by_kind[kind] = result.events_by_kind.get(kind, 0) + 1
        result.events_by_agent[ev.agent] = result.events_by_agent.get(ev.agent, 0) + 1
    for name, rec in sorted(record.agents.items()):
        states = [c.state for c in rec.mc_states]
        if "MISSION" in states:
            result.flew_mission.append(name)
        if states and states[-1] == "STANDBY" and rec.telemetry and not rec.telemetry[-1].in_air:
            result.landed.append(name)
    return result


def _fence_samples(
    fence: Geofence,
    where: dict[str, tuple[float, float, float]],
    t: float,
    open_out: dict[str, list[float | str]],
    result: SafetyAnalysis,
) -> None:
    for name, (n, e, u) in where.items():
        breach = fence.breach(n, e, u)
        if breach.startswith("below") and u < GROUND_HEIGHT:
            breach = ""  # taking off or landing through the floor on its own spot
        if breach:
            depth = _depth(fence, n, e, u)
            cur = open_out.get(name)
            if cur is None:
                open_out[name] = [t, t, depth, t, breach]
            else:
                cur[1] = t
                if depth > float(cur[2]):
                    cur[2], cur[3], cur[4] = depth, t, breach
        elif name in open_out:
            _close_breach(name, open_out, result, t)
    for name in [a for a in open_out if a not in where]:
        _close_breach(name, open_out, result, t)


def _depth(fence: Geofence, north: float, east: float, up: float) -> float:
    """How far (m) outside the fence a point is: beyond the nearest edge, above the ceiling, below the floor."""
    if not fence.inside_polygon(north, east):
        return fence.edge_distance(north, east)
    return up - fence.ceiling if up > fence.ceiling else fence.floor - up


def _close_breach(
    agent: str, open_out: dict[str, list[float | str]], result: SafetyAnalysis, t: float
) -> None:
    s, e, depth, when, what = open_out.pop(agent)
    result.breaches.append(Encounter(agent, "", float(s), float(e), float(depth), float(when), str(what)))


def format_safety(s: SafetyAnalysis, *, shown: int = 10) -> list[str]:
    """The safety section of ``antalate analyze``'s summary."""
    lim = s.limits
    shape = f"half-height {lim.vertical:g} m" if lim.vertical else "3-D distance"
    lines = [
        f"safety (radius {lim.radius:g} m, {shape}, documented margin {lim.margin:g} m; docs/safety.md):"
    ]
    floor = lim.radius - lim.margin
    if s.min_separation is None or s.min_pair is None or s.min_t is None:
        lines.append("  min separation     - (never two agents in the air at once)")
    else:
        verdict = "OK" if s.min_separation >= floor else "BELOW"
        lines.append(
            f"  min separation     {s.min_separation:.2f} m at {s.min_t:.1f} s ({s.min_pair[0]}, {s.min_pair[1]}; "
            f"3-D {s.min_separation_3d:.2f} m) over {s.samples} samples of every agent in the air; "
            f"radius - margin = {floor:.2f} m: {verdict}"
        )
    lines.append(
        f"  near-misses        {len(s.near_misses)} encounter(s) closer than {lim.threshold:g} m, "
        f"{len(s.losses)} closer than {floor:.2f} m (losses of separation)"
    )
    for e in s.near_misses[:shown]:
        lines.append(f"    {e.a}, {e.b}: {e.distance:.2f} m at {e.t:.1f} s ({e.start:.1f} .. {e.end:.1f} s)")
    if len(s.near_misses) > shown:
        lines.append(f"    ... {len(s.near_misses) - shown} more")
    if lim.fence is None:
        lines.append("  fence breaches     - (no fence given)")
    else:
        lines.append(f"  fence breaches     {len(s.breaches)}")
        for e in s.breaches[:shown]:
            lines.append(f"    {e.a}: {e.start:.1f} .. {e.end:.1f} s, worst at {e.t:.1f} s: {e.what}")
    total = sum(s.events_by_kind.values())
    kinds = ", ".join(f"{k} {n}" for k, n in sorted(s.events_by_kind.items()))
    lines.append(
        f"  SAFETY reports     {total}"
        + (f" ({kinds}) from {len(s.events_by_agent)} agent(s)" if total else "")
    )
    for ev in s.examples:
        lines.append(f"    {ev.t:.1f} s {ev.agent}: {ev.text}")
    lines.append(
        f"  mission            {len(s.flew_mission)} of {s.agents} agent(s) flew MISSION; "
        f"{len(s.landed)} back in STANDBY on the ground at the end"
    )
    return lines
