"""Fly the shipped peer behaviors (gathering, flocking) with 8 simulated agents and judge the flight
from its LCM log: the same configs and the same verdict in every launch mode (tests/agent/test_peer_flights.py).

Each agent's config holds the whole experiment: ``auto_operator`` takes off once and orders RTL after
``mission`` seconds, the swarm rule flies the mission, and ``peer_sensor`` (identities on, unlimited
range) publishes what the agent hears of its peers, so "every agent hears all 7 peers" is read from the
log like everything else. The verdict is computed from the recorded telemetry only.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lcm
import tomli_w

from antalate_lcm.base import geo
from antalate_lcm.msgs import mc_state_t, peer_scan_t, telemetry_t
from antalate_lcm.vehicles.sim import DEFAULTS as SIM_DEFAULTS
from antalate_lcm.wire.vocabulary import McState
from tests.harness.agents import agent_config

AGENTS = 8
BASE = "sw"
NAMES = [f"{BASE}-{i:02d}" for i in range(1, AGENTS + 1)]
KEY = "peer-flight-swarm-key"
#: m between homes (antalate agent --spacing): a 3 x 3 grid, 8 of its places used.
SPACING = 6.0
ALTITUDE = 4.0
SEPARATION = 3.0
#: s in MISSION before the operator behavior orders RTL.
MISSION = {"gathering": 14.0, "flocking": 12.0}
BEHAVIOR_PARAMS: dict[str, dict[str, Any]] = {
    "gathering": {"separation": SEPARATION},
    "flocking": {"separation": SEPARATION, "speed": 1.5},
}


def home(i: int) -> tuple[float, float]:
    """The home of the i-th agent (0-based): ``swarm_configs``' grid, so --agents N and per-agent
    configs put the same vehicle at the same place."""
    side = math.ceil(math.sqrt(AGENTS))
    return geo.offset(
        SIM_DEFAULTS["home_lat"], SIM_DEFAULTS["home_lon"], (i // side) * SPACING, (i % side) * SPACING
    )


def config_doc(
    behavior: str, bus_url: str, state_dir: Path, *, name: str = BASE, index: int | None = None
) -> dict[str, Any]:
    """One agent's config (``index`` set: that agent's own name and home; else the base of --agents 8)."""
    home_at: dict[str, Any] = {}
    if index is not None:
        home_at["home_lat"], home_at["home_lon"] = home(index)
        name = NAMES[index]
    return agent_config(
        name,
        sim=home_at,
        bus=bus_url,
        takeoff=ALTITUDE,
        security={"swarm_key": KEY, "state_dir": str(state_dir)},
        bma=[
            {
                "name": "operator",
                "behaviors": [
                    {
                        "plugin": "auto_operator",
                        "params": {"rtl_after": MISSION[behavior], "max_flights": 1, "retry": 1.0},
                    }
                ],
            },
            {
                "name": "swarm",
                "behaviors": [
                    {"plugin": behavior, "params": BEHAVIOR_PARAMS[behavior]},
                    {"plugin": "peer_sensor", "params": {"max_range": 1000.0, "identities": True}},
                ],
            },
        ],
    )


def write_config(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(tomli_w.dumps(doc))
    return path


@dataclass
class Flight:
    """What the log says each agent did: telemetry (t, north, east, vn, ve), MC states, peer scans."""

    telemetry: dict[str, list[tuple[float, float, float, float, float]]] = field(default_factory=dict)
    states: dict[str, list[tuple[float, str]]] = field(default_factory=dict)
    #: Per agent: (t, the set of peer names in one scan).
    scans: dict[str, list[tuple[float, frozenset[str]]]] = field(default_factory=dict)

    def first(self, agent: str, state: str) -> float | None:
        return next((t for t, s in self.states.get(agent, []) if s == state), None)

    def mission_window(self) -> tuple[float, float] | None:
        """From the moment every agent is in MISSION to the first RTL (None until both happened)."""
        starts = [self.first(a, "MISSION") for a in NAMES]
        ends = [self.first(a, "RTL") for a in NAMES]
        if any(t is None for t in starts) or all(t is None for t in ends):
            return None
        return max(t for t in starts if t is not None), min(t for t in ends if t is not None)

    def all_returning(self) -> bool:
        return all(self.first(a, "RTL") is not None for a in NAMES)

    def snapshot(self, t: float) -> dict[str, tuple[float, float, float, float]]:
        """Every agent's last (north, east, vn, ve) at or before ``t``."""
        out = {}
        for agent, samples in self.telemetry.items():
            before = [s for s in samples if s[0] <= t]
            if before:
                out[agent] = before[-1][1:]
        return out


def read_flight(path: Path) -> Flight:
    """Decode a (possibly still growing) log; an unfinished last event ends the reading."""
    flight = Flight()
    lat0, lon0 = home(0)
    frame = geo.FlatFrame(lat0, lon0)
    log = lcm.EventLog(str(path), "r")
    start: int | None = None
    try:
        while True:
            try:
                event = log.read_next_event()
            except (OSError, ValueError):
                break
            if event is None:
                break
            start = event.timestamp if start is None else start
            t = (event.timestamp - start) / 1e6
            agent, _, topic = event.channel.partition("/")
            if agent not in NAMES:
                continue
            try:
                if topic == "TELEMETRY":
                    m = telemetry_t.decode(event.data)
                    n, e = frame.to_ne(m.lat, m.lon)
                    flight.telemetry.setdefault(agent, []).append((t, n, e, m.vn, m.ve))
                elif topic == "MC_STATE":
                    s = McState(mc_state_t.decode(event.data).state).name
                    states = flight.states.setdefault(agent, [])
                    if not states or states[-1][1] != s:
                        states.append((t, s))
                elif topic == "PEER_SCAN":
                    scan = peer_scan_t.decode(event.data)
                    flight.scans.setdefault(agent, []).append((t, frozenset(scan.id)))
            except (ValueError, KeyError):
                continue
    finally:
        log.close()
    return flight


def radius(points: list[tuple[float, float]]) -> float:
    cn = sum(p[0] for p in points) / len(points)
    ce = sum(p[1] for p in points) / len(points)
    return max(math.hypot(p[0] - cn, p[1] - ce) for p in points)


def min_separation(flight: Flight, start: float, end: float, step: float = 0.1) -> tuple[float, float, str]:
    """The smallest horizontal distance between two agents over [start, end]: (metres, when, which pair)."""
    best = (math.inf, start, "")
    t = start
    while t <= end:
        snap = flight.snapshot(t)
        for a, b in itertools.combinations(sorted(snap), 2):
            d = math.hypot(snap[a][0] - snap[b][0], snap[a][1] - snap[b][1])
            if d < best[0]:
                best = (d, t, f"{a}-{b}")
        t += step
    return best


def polarisation(snap: dict[str, tuple[float, float, float, float]]) -> float:
    """|mean of the unit velocity vectors| (Vicsek's order parameter): 1 = all fly one way."""
    units = [
        (vn / math.hypot(vn, ve), ve / math.hypot(vn, ve))
        for _, _, vn, ve in snap.values()
        if math.hypot(vn, ve) > 0.05
    ]
    if len(units) < len(snap):
        return 0.0  # an agent standing still is not aligned with anything
    return math.hypot(sum(u[0] for u in units), sum(u[1] for u in units)) / len(units)


def heard_everyone(flight: Flight, start: float, end: float) -> dict[str, int]:
    """Per agent: the most peers one of its scans in [start, end] named."""
    return {
        agent: max((len(ids) for t, ids in flight.scans.get(agent, []) if start <= t <= end), default=0)
        for agent in NAMES
    }


@dataclass(frozen=True)
class Verdict:
    heard: dict[str, int]
    final_radius: float
    min_separation: tuple[float, float, str]
    polarisation: float


def judge(flight: Flight) -> Verdict:
    window = flight.mission_window()
    assert window is not None, f"no mission in the log: states {flight.states}"
    start, end = window
    final = flight.snapshot(end)
    assert sorted(final) == NAMES, f"telemetry of {sorted(final)} only"
    return Verdict(
        heard=heard_everyone(flight, start, end),
        final_radius=radius([(v[0], v[1]) for v in final.values()]),
        min_separation=min_separation(flight, start, end),
        polarisation=sum(polarisation(flight.snapshot(end - k * 0.5)) for k in range(4)) / 4,
    )
