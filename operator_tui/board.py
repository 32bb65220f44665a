"""What the console knows about the swarm, built only from decoded messages (pure: no Textual, no LCM I/O).

Keeping this apart from the UI means the rules an operator relies on — when an agent is *stale*,
which transitions reach the event log, what "last error" means — are tested without a terminal,
and the UI only formats what is here. Time is always passed in (``now`` on a monotonic clock for
ages and staleness, ``wall`` in Unix seconds for the log's timestamps), so tests drive it with a
fake clock.

The log holds what changed, not what is: an agent's first states are in the table, so only its
discovery is logged (and a first state that is already bad: ERROR, LLC_DOWN, LOW_BATTERY) — with
200 agents, the start would otherwise push 600 lines through the log.

An agent is never removed once seen: a vehicle that falls silent is exactly the one the operator
must keep looking at, so it is marked stale instead.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from antalate_lcm.agent.hlc.machine import ErrorCode
from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.geo import FlatFrame, wrap_360
from antalate_lcm.wire.vocabulary import HlcState, McState, Severity, name_of

#: The topics the board understands (config topic names).
WATCHED_TOPICS: tuple[str, ...] = ("MC_STATE", "HLC_STATE", "TELEMETRY", "HLC_ERROR", "ARBITER")


class EventKind(enum.Enum):
    DISCOVERED = "discovered"
    MC = "mc"
    HLC = "hlc"
    ERROR = "error"
    STALE = "stale"
    ALIVE = "alive"
    BEHAVIOR = "behavior"
    COMMAND = "command"


@dataclass(frozen=True)
class Event:
    """One line of the event log."""

    wall: float
    agent: str
    kind: EventKind
    text: str
    severity: Severity = Severity.INFO


@dataclass(frozen=True, slots=True)
class Telemetry:
    """The fields of ``telemetry_t`` the console shows (copied: the message object may be reused)."""

    lat: float
    lon: float
    alt: float
    heading: float
    vn: float
    ve: float
    vd: float
    battery: float
    armed: bool
    in_air: bool
    mode: str

    @classmethod
    def from_msg(cls, msg: Any) -> Telemetry:
        return cls(
            msg.lat,
            msg.lon,
            msg.alt,
            msg.heading,
            msg.vn,
            msg.ve,
            msg.vd,
            msg.battery,
            msg.armed,
            msg.in_air,
            msg.mode,
        )

    @property
    def ground_speed(self) -> float:
        return math.hypot(self.vn, self.ve)

    @property
    def has_fix(self) -> bool:
        """False for (0, 0) and non-finite positions, which autopilots send before they have one."""
        return (
            math.isfinite(self.lat) and math.isfinite(self.lon) and not (self.lat == 0.0 and self.lon == 0.0)
        )


@dataclass(frozen=True)
class ErrorReport:
    """The latest ``hlc_error_t`` of an agent."""

    code: int
    severity: Severity
    text: str
    wall: float
    at: float


@dataclass
class ArbiterView:
    state: str = ""
    active: tuple[str, ...] = ()
    failed: tuple[str, ...] = ()


@dataclass
class AgentView:
    """Everything known about one agent; ``None`` fields have not been heard yet."""

    name: str
    last_heard: float
    mc_state: str | None = None
    mc_reason: str = ""  # mc_state_t.reason: why the MC is in its state
    last_command_seq: int | None = None
    hlc_state: str | None = None
    hlc_reason: str = ""  # hlc_state_t.reason
    autopilot: str = ""
    telemetry: Telemetry | None = None
    arbiters: dict[str, ArbiterView] = field(default_factory=dict)
    last_error: ErrorReport | None = None
    errors: int = 0
    #: The latest SAFETY report (the filter modified a command: by whom, the nearest peer and its
    #: distance), kept apart so a later error of another kind does not hide it (docs/safety.md).
    last_safety: ErrorReport | None = None
    stale: bool = False
    #: Last time each topic was heard from this agent (so the detail view can say *what* went quiet).
    heard: dict[str, float] = field(default_factory=dict)
    messages: int = 0

    def link_age(self, now: float) -> float:
        return max(0.0, now - self.last_heard)

    @property
    def active_behaviors(self) -> tuple[str, ...]:
        """Active behaviors of every arbiter, in arbiter-name order (what the table's column shows)."""
        return tuple(b for _, arb in sorted(self.arbiters.items()) for b in arb.active)

    @property
    def failed_behaviors(self) -> tuple[str, ...]:
        return tuple(b for _, arb in sorted(self.arbiters.items()) for b in arb.failed)


class SwarmBoard:
    """Agents by name, plus the event log, updated from decoded messages.

    The UI calls :meth:`apply` for every message it drains, :meth:`tick` on its refresh timer, and
    reads :attr:`agents` and :meth:`take_events`.
    """

    def __init__(self, *, stale_after: float = 3.0, max_events: int = 2000) -> None:
        if not stale_after > 0:
            raise ValueError("stale_after must be > 0")
        self.stale_after = stale_after
        self.agents: dict[str, AgentView] = {}
        self.events: deque[Event] = deque(maxlen=max_events)
        self._new_events: list[Event] = []
        #: The map's reference point: the first position fix heard (stable, unlike a mean).
        self.origin: FlatFrame | None = None
        self.messages = 0

    # ------------------------------------------------------------------ input
    def apply(
        self, topic: str, agent: str, msg: Any, now: float, wall: float, fields: dict[str, str] | None = None
    ) -> None:
        """Fold one decoded message from ``agent`` (the name recovered from its channel) into the board."""
        view = self.heard(topic, agent, now, wall)
        handler = self._handlers.get(topic)
        if handler is not None:
            handler(self, view, msg, now, wall, fields or {})

    def fold(
        self, topic: str, agent: str, msg: Any, now: float, wall: float, fields: dict[str, str] | None = None
    ) -> None:
        """Fold in a message whose arrival :meth:`heard` already noted (the console decodes an
        off-screen agent's telemetry only when it is shown); nothing if the agent is unknown."""
        view = self.agents.get(agent)
        handler = self._handlers.get(topic)
        if view is not None and handler is not None:
            handler(self, view, msg, now, wall, fields or {})

    def heard(self, topic: str, agent: str, now: float, wall: float) -> AgentView:
        """Note that ``agent`` was heard on ``topic`` (alive again if it was stale) without a new
        message to fold in: what a state republished unchanged needs (most of them, at 5 Hz)."""
        view = self.agents.get(agent)
        if view is None:
            view = self.agents[agent] = AgentView(agent, now)
            self._event(wall, agent, EventKind.DISCOVERED, f"discovered (first heard on {topic})")
        elif view.stale:
            view.stale = False
            self._event(
                wall, agent, EventKind.ALIVE, f"heard again after {now - view.last_heard:.1f} s of silence"
            )
        view.last_heard = now
        view.heard[topic] = now
        view.messages += 1
        self.messages += 1
        return view

    def _on_mc(self, view: AgentView, msg: Any, now: float, wall: float, fields: dict[str, str]) -> None:
        name = name_of(McState, msg.state) or f"?{msg.state}"  # a newer agent's state: shown, not dropped
        view.mc_reason = getattr(msg, "reason", "")
        if name != view.mc_state:
            old = view.mc_state
            view.mc_state = name
            sev = {"ERROR": Severity.ERROR, "HLC_LOST": Severity.ERROR, "HOLD": Severity.WARNING}.get(
                name, Severity.INFO
            )
            if old is not None or sev is not Severity.INFO:  # a first state is news only when it is bad
                why = f": {view.mc_reason}" if view.mc_reason else ""
                self._event(wall, view.name, EventKind.MC, f"MC {old or '—'} → {name}{why}", sev)
        view.last_command_seq = msg.last_command_seq

    def _on_hlc(self, view: AgentView, msg: Any, now: float, wall: float, fields: dict[str, str]) -> None:
        name = name_of(HlcState, msg.state) or f"?{msg.state}"
        view.autopilot = msg.autopilot
        view.hlc_reason = getattr(msg, "reason", "")
        if name != view.hlc_state:
            old = view.hlc_state
            view.hlc_state = name
            sev = {
                "LLC_DOWN": Severity.CRITICAL,
                "LOW_BATTERY": Severity.WARNING,
                "HOLD": Severity.WARNING,
            }.get(name, Severity.INFO)
            if old is not None or sev is not Severity.INFO:
                why = f": {view.hlc_reason}" if view.hlc_reason else ""
                self._event(wall, view.name, EventKind.HLC, f"HLC {old or '—'} → {name}{why}", sev)

    def _on_telemetry(
        self, view: AgentView, msg: Any, now: float, wall: float, fields: dict[str, str]
    ) -> None:
        tel = Telemetry.from_msg(msg)
        view.telemetry = tel
        if self.origin is None and tel.has_fix:
            self.origin = FlatFrame(tel.lat, tel.lon)

    def _on_error(self, view: AgentView, msg: Any, now: float, wall: float, fields: dict[str, str]) -> None:
        try:
            sev = Severity(msg.severity)
        except ValueError:
            sev = Severity.ERROR
        view.last_error = ErrorReport(msg.code, sev, msg.text, wall, now)
        if msg.code == ErrorCode.SAFETY:
            view.last_safety = view.last_error
        view.errors += 1
        self._event(wall, view.name, EventKind.ERROR, f"[{sev.name} {msg.code}] {msg.text}", sev)

    def _on_arbiter(self, view: AgentView, msg: Any, now: float, wall: float, fields: dict[str, str]) -> None:
        name = msg.arbiter or fields.get("arbiter", "")
        arb = view.arbiters.get(name)
        if arb is None:
            arb = view.arbiters[name] = ArbiterView()
        active = tuple(msg.active[: msg.n])
        failed = tuple(getattr(msg, "failed", ())[: getattr(msg, "n_failed", 0)])
        for fail in failed:
            if fail not in arb.failed:
                self._event(
                    wall, view.name, EventKind.BEHAVIOR, f"behavior failed in {name}: {fail}", Severity.ERROR
                )
        arb.state, arb.active, arb.failed = msg.state, active, failed

    _handlers = {
        "MC_STATE": _on_mc,
        "HLC_STATE": _on_hlc,
        "TELEMETRY": _on_telemetry,
        "HLC_ERROR": _on_error,
        "ARBITER": _on_arbiter,
    }

    # ------------------------------------------------------------------ time
    def tick(self, now: float, wall: float) -> None:
        """Mark agents silent for longer than ``stale_after`` as stale (once, with an event)."""
        limit = now - self.stale_after
        for view in self.agents.values():
            if not view.stale and view.last_heard < limit:
                view.stale = True
                self._event(
                    wall,
                    view.name,
                    EventKind.STALE,
                    f"silent for {now - view.last_heard:.1f} s: marked stale",
                    Severity.WARNING,
                )

    # ------------------------------------------------------------------ output
    def log(self, wall: float, agent: str, text: str, severity: Severity = Severity.INFO) -> None:
        """Add a console event (commands sent, acknowledged, failed) to the same log."""
        self._event(wall, agent, EventKind.COMMAND, text, severity)

    def _event(
        self, wall: float, agent: str, kind: EventKind, text: str, severity: Severity = Severity.INFO
    ) -> None:
        ev = Event(wall, agent, kind, text, severity)
        self.events.append(ev)
        self._new_events.append(ev)

    def take_events(self) -> list[Event]:
        """Events added since the last call (the UI appends them to its log widget)."""
        out, self._new_events = self._new_events, []
        return out

    def names(self) -> list[str]:
        """Agent names in natural order (``a2`` before ``a10``), the table's order."""
        return sorted(self.agents, key=natural_key)

    def mc_state_of(self, agent: str) -> str | None:
        """The MC state last heard from ``agent`` (None: never heard): what the command tracker checks
        a command against."""
        view = self.agents.get(agent)
        return None if view is None else view.mc_state

    def is_stale(self, agent: str) -> bool:
        view = self.agents.get(agent)
        return view is not None and view.stale

    def live_names(self) -> list[str]:
        return [n for n in self.names() if not self.agents[n].stale]

    @property
    def stale_count(self) -> int:
        return sum(1 for v in self.agents.values() if v.stale)

    def positions(self) -> Iterator[tuple[AgentView, float, float]]:
        """(agent, north m, east m) from :attr:`origin` for every agent with a position fix."""
        if self.origin is None:
            return
        for view in self.agents.values():
            tel = view.telemetry
            if tel is not None and tel.has_fix:
                north, east = self.origin.to_ne(tel.lat, tel.lon)
                yield view, north, east

    def safety_summary(self, now: float, *, recent: float = 2.0, reach: float = 20.0) -> SafetySummary | None:
        """What the status bar says of the separation filter (docs/safety.md): how many agents had
        their command modified in the last `recent` s (by separation, fence or both), and the closest
        pair of agents in the air within `reach` m. None until a SAFETY report was heard at all (a
        swarm without the filter shows nothing)."""
        reports = [v.last_safety for v in self.agents.values() if v.last_safety is not None]
        if not reports:
            return None
        modified: dict[str, int] = {}
        for r in reports:
            if now - r.at <= recent and "modified by " in r.text:
                by = r.text.split("modified by ", 1)[1].split(";", 1)[0].strip()
                modified[by] = modified.get(by, 0) + 1
        # The closest pair by a grid of `reach`-wide cells: every pair within `reach` is in
        # neighbouring cells, and a thousand agents cost a thousand lookups, not half a million.
        cells: dict[tuple[int, int], list[tuple[str, float, float, float]]] = {}
        for view, north, east in self.positions():
            tel = view.telemetry
            if tel is None or not tel.in_air or view.stale:
                continue
            key = (math.floor(north / reach), math.floor(east / reach))
            cells.setdefault(key, []).append((view.name, north, east, tel.alt))
        closest: tuple[float, str, str] | None = None
        for (ci, cj), members in cells.items():
            near = [m for di in (-1, 0, 1) for dj in (-1, 0, 1) for m in cells.get((ci + di, cj + dj), ())]
            for a in members:
                for b in near:
                    if b[0] <= a[0]:
                        continue
                    d = math.dist(a[1:], b[1:])
                    if d <= reach and (closest is None or d < closest[0]):
                        closest = (d, a[0], b[0])
        return SafetySummary(modified, closest)


@dataclass(frozen=True)
class SafetySummary:
    #: Agents whose command was modified lately, by who modified it ("separation", "fence", ...).
    modified: dict[str, int]
    #: (3-D distance m, a, b) of the closest pair in the air within reach; None when none is that close.
    closest: tuple[float, str, str] | None


def natural_key(name: str) -> tuple[Any, ...]:
    """Sort key that orders embedded numbers numerically (``uav2`` < ``uav10``)."""
    out: list[Any] = []
    num = ""
    text = ""
    for ch in name:
        if ch.isdigit():
            if text:
                out.append((1, text))
                text = ""
            num += ch
        else:
            if num:
                out.append((0, int(num)))
                num = ""
            text += ch
    if num:
        out.append((0, int(num)))
    if text:
        out.append((1, text))
    return tuple(out)


def heading_arrow(heading: float) -> str:
    """One of eight arrows for a heading (deg from north, clockwise): how the map and table draw it."""
    if not math.isfinite(heading):
        return "?"
    return "↑↗→↘↓↙←↖"[int((wrap_360(heading) + 22.5) // 45) % 8]


def join_limited(items: Iterable[str], width: int) -> str:
    """Comma-join, cut with an ellipsis to ``width`` characters (table cells have fixed widths)."""
    text = ", ".join(items)
    return text if len(text) <= width else text[: max(0, width - 1)] + "…"


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
