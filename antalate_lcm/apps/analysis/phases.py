"""The phases of a flight, from the agents' MC states (pure: a function of the decoded record).

* **mission**: from the moment the *last* agent entered MISSION to the moment the *first* one left
  it (or the end of the log): the span in which the whole swarm was flying its mission. Without MC
  states in the log, the span in which every agent's telemetry says ``in_air``.
* **takeoff**: from the first agent's TAKEOFF to the mission's start (the swarm climbing and
  gathering its members into MISSION; the first telemetry in the air without MC states).
* **return**: from the mission's end until every agent that flew it was back on the ground: the
  latest of each agent's first STANDBY after the mission (or its last telemetry, if it never got
  there; the last ``in_air`` telemetry without MC states).

RTL legs and climbs are kept apart from the mission this way: a swarm metric over the mission never
mixes in the flight home, where every agent heads for its own home point.
"""

from __future__ import annotations

from dataclasses import dataclass

from antalate_lcm.apps.analysis.records import SwarmRecord

#: The phases, in flight order.
PHASES = ("takeoff", "mission", "return")


@dataclass(frozen=True)
class Window:
    start: float
    end: float
    #: How the window was found (for the summary).
    how: str

    @property
    def length(self) -> float:
        return self.end - self.start


@dataclass(frozen=True)
class FlightPhase(Window):
    """One phase of the flight: ``name`` is one of :data:`PHASES`."""

    name: str = "mission"


def mission_window(record: SwarmRecord) -> Window | None:
    """The span in which every agent was flying its mission (see the module docstring)."""
    entries: list[float] = []
    exits: list[float] = []
    for rec in record.agents.values():
        states = rec.mc_states
        first = next((i for i, c in enumerate(states) if c.state == "MISSION"), None)
        if first is None:
            continue
        entries.append(states[first].t)
        left = next((c.t for c in states[first + 1 :] if c.state != "MISSION"), None)
        exits.append(left if left is not None else record.duration)
    if entries:
        start, end = max(entries), min(exits)
        if end > start:
            n = len(entries)
            return Window(start, end, f"all {n} agent(s) that flew a mission were in MISSION")
        return None
    spans = []
    for rec in record.agents.values():
        airborne = [s.t for s in rec.telemetry if s.in_air]
        if airborne:
            spans.append((airborne[0], airborne[-1]))
    if spans:
        start, end = max(a for a, _ in spans), min(b for _, b in spans)
        if end > start:
            return Window(start, end, "no MC states in the log: every agent's telemetry said in_air")
    return None


def flight_phases(record: SwarmRecord, window: Window | None = None) -> list[FlightPhase]:
    """The takeoff, mission and return phases that the log holds, in order (see the module docstring).

    ``window`` is the mission window if already computed (:func:`mission_window` otherwise).
    """
    window = window if window is not None else mission_window(record)
    if window is None:
        return []
    with_states = any(rec.mc_states for rec in record.agents.values())
    phases: list[FlightPhase] = []
    if with_states:
        takeoffs = [c.t for rec in record.agents.values() for c in rec.mc_states if c.state == "TAKEOFF"]
        takeoffs = [t for t in takeoffs if t < window.start]
        if takeoffs:
            phases.append(FlightPhase(min(takeoffs), window.start, "first TAKEOFF to the mission", "takeoff"))
    else:
        airborne = [s.t for rec in record.agents.values() for s in rec.telemetry if s.in_air]
        if airborne and min(airborne) < window.start:
            phases.append(FlightPhase(min(airborne), window.start, "first in_air to the mission", "takeoff"))
    phases.append(FlightPhase(window.start, window.end, window.how, "mission"))
    ends: list[float] = []
    for rec in record.agents.values():
        if with_states:
            if not any(c.state == "MISSION" for c in rec.mc_states):
                continue
            home = next((c.t for c in rec.mc_states if c.t > window.end and c.state == "STANDBY"), None)
            last = rec.telemetry[-1].t if rec.telemetry else rec.last_heard
            ends.append(home if home is not None else last)
        else:
            airborne = [s.t for s in rec.telemetry if s.in_air]
            if airborne:
                ends.append(airborne[-1])
    end = max(ends, default=window.end)
    if end > window.end:
        how = (
            "mission end to every agent back in STANDBY" if with_states else "mission end to the last in_air"
        )
        phases.append(FlightPhase(window.end, end, how, "return"))
    return phases
