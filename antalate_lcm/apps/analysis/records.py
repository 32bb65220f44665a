"""What a log holds once decoded: plain data, no I/O (the metrics and the plots only see these).

Times are seconds since the log's first event, on the logger's clock: every message in one log is
stamped by one clock, whereas ``header.utime`` comes from each sender's own clock and may be skewed
between vehicle computers.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class TelemetrySample:
    """One ``telemetry_t``: what the analysis needs of it."""

    t: float
    lat: float
    lon: float
    alt: float
    heading: float
    in_air: bool
    battery: float
    #: Velocity north and east (m/s), as the vehicle reported it (0 in logs of older versions).
    vn: float = 0.0
    ve: float = 0.0


@dataclass(frozen=True, slots=True)
class StateChange:
    """A state first heard at ``t`` (repeats of the same state are folded into it)."""

    t: float
    state: str


@dataclass(frozen=True, slots=True)
class DirectionCommand:
    """A change of the operator's direction (``direction_cmd_t``); repeats are folded into it."""

    t: float
    active: bool
    azimuth: float
    speed: float
    #: Agent the command was for; "" = every agent (the broadcast channel or an empty target).
    target: str
    #: ``header.agent`` of the sender (the operator console's name).
    sender: str


@dataclass(frozen=True, slots=True)
class FaultRecord:
    """A fault an experiment's script injected (``antalate run``: docs/experiments.md, "Faults"), or
    an agent's broadcast reception, as recorded on the fault channel."""

    #: s since the log's first event
    t: float
    agent: str
    #: crash, freeze, sensor, byzantine, battery, link_loss, packet_loss; or broadcast
    kind: str
    #: start, end, spared (the probability drew no fault); summary (broadcast)
    event: str
    #: The rest of the record: the fault's keys (duration, offset, ...), or offered/heard.
    detail: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class SafetyEvent:
    """A SAFETY report of an agent's HLC (``hlc_error_t`` code 14, docs/safety.md): its command was
    modified (by separation or fence), it could not keep a constraint, it had no peer information,
    or its fence was mirrored into the autopilot."""

    t: float
    agent: str
    #: ``hlc_error_t.severity``: 0 INFO, 1 WARNING, 2 ERROR, 3 CRITICAL.
    severity: int
    text: str


@dataclass
class AgentRecord:
    """Everything one agent published that the analysis uses."""

    name: str
    telemetry: list[TelemetrySample] = field(default_factory=list)
    mc_states: list[StateChange] = field(default_factory=list)
    hlc_states: list[StateChange] = field(default_factory=list)
    #: Time of the agent's last message of any kind the log holds.
    last_heard: float = 0.0

    def add_state(self, which: list[StateChange], t: float, state: str) -> None:
        if not which or which[-1].state != state:
            which.append(StateChange(t, state))


@dataclass
class SwarmRecord:
    """A decoded log: every agent's record, the operator's directions, and what was left out."""

    path: str
    #: Microseconds since the epoch of the first event (the origin of every ``t``).
    start_utime: int = 0
    duration: float = 0.0
    events: int = 0
    agents: dict[str, AgentRecord] = field(default_factory=dict)
    directions: list[DirectionCommand] = field(default_factory=list)
    faults: list[FaultRecord] = field(default_factory=list)
    #: Every SAFETY report of the agents' HLCs, in log order.
    safety_events: list[SafetyEvent] = field(default_factory=list)
    #: Events on antalate channels that did not decode as their type (garbage, other versions), by channel.
    undecodable: dict[str, int] = field(default_factory=dict)
    #: Events on channels that are not antalate's, by channel.
    unknown: dict[str, int] = field(default_factory=dict)
    #: Events on antalate channels the analysis does not use (velocity commands, arbiters, ...), by topic.
    unused: dict[str, int] = field(default_factory=dict)
    #: Why reading stopped before the end of the file (a truncated or corrupted log), or "".
    truncated: str = ""

    def agent(self, name: str) -> AgentRecord:
        rec = self.agents.get(name)
        if rec is None:
            rec = self.agents[name] = AgentRecord(name)
        return rec

    @property
    def skipped(self) -> int:
        return sum(self.undecodable.values()) + sum(self.unknown.values())
