"""The station's state and rules, independent of HTTP: agents, tokens, the command queue, sensing.

Every method takes the current time as an argument (no clock of its own) and is called from one
thread, the server's event loop, so the in-memory state needs no locks. The database is the
source of truth for tokens and commands (written before a reply depends on them); the in-memory
copies exist so that a report costs dictionary look-ups, not queries.
"""

from __future__ import annotations

import logging
import math
import secrets
from collections import deque
from dataclasses import dataclass, field

from . import sector
from ._db import AgentRow, LatestState, StationDB
from ._models import (
    AgentInfo,
    CommandRequest,
    CommandResponse,
    DirectionCommand,
    OperatorCommand,
    Payload,
    PeerDetection,
    QueuedCommand,
    ReportReply,
    ReportRequest,
    Telemetry,
)
from ._settings import StationSettings
from ._spatial import GridIndex

log = logging.getLogger("antalate.station")


class UnknownTarget(LookupError):
    """A command addressed to a name or token the station has never seen."""


@dataclass(slots=True)
class _Agent:
    token: str
    name: str
    first_seen: float
    last_seen: float | None = None
    mc_state: str | None = None
    hlc_state: str | None = None
    telemetry: Telemetry | None = None


@dataclass(slots=True)
class _Queue:
    """One agent's undelivered commands: operator commands in order, at most one direction."""

    operator: deque[tuple[int, float, OperatorCommand]] = field(default_factory=deque)
    direction: tuple[int, float, DirectionCommand] | None = None

    def __bool__(self) -> bool:
        return bool(self.operator) or self.direction is not None


class Station:
    """Agents' registry, command queue and sector sensing over a `StationDB`."""

    def __init__(self, settings: StationSettings, db: StationDB) -> None:
        self.settings = settings
        self.db = db
        # Half the range per cell: a 60° sector's box then spans about 3×3 cells.
        self.index = GridIndex(settings.range_m / 2.0)
        self._agents: dict[str, _Agent] = {}
        self._queues: dict[str, _Queue] = {}
        for row in db.load_agents():
            self._adopt(row)
        for p in db.load_pending():
            queue = self._queues.setdefault(p.token, _Queue())
            if p.kind == "operator":
                queue.operator.append((p.seq, p.t, OperatorCommand.model_validate({**p.body, "seq": p.seq})))
            else:
                queue.direction = (p.seq, p.t, DirectionCommand.model_validate({**p.body, "seq": p.seq}))
        log.info(
            "station: %d agent(s) and %d pending command(s) from %s; range %.1f m, field of view %.1f°",
            len(self._agents), sum(len(q.operator) + (q.direction is not None) for q in self._queues.values()),
            db.path, settings.range_m, settings.fov_deg,
        )

    def _adopt(self, row: AgentRow) -> None:
        self._agents[row.token] = _Agent(
            row.token, row.name, row.first_seen, row.last_seen, row.mc_state, row.hlc_state, row.telemetry
        )
        if row.telemetry is not None and row.last_seen is not None:
            self.index.update(row.token, row.telemetry.lat, row.telemetry.lon, row.last_seen)

    # -- reports ---------------------------------------------------------------------------------

    def report(self, req: ReportRequest, now: float) -> ReportReply:
        """Record one report and build its reply: token, due commands, peer detection."""
        agent = self._agents.get(req.token) if req.token is not None else None
        tel = req.telemetry
        if agent is None:
            agent = self._new_agent(tel.agent if tel is not None and tel.agent else None, now, req.token)
        agent.last_seen = now
        if req.mc_state is not None:
            agent.mc_state = req.mc_state
        if req.hlc_state is not None:
            agent.hlc_state = req.hlc_state
        payload = None
        if tel is not None:
            agent.telemetry = tel
            if tel.agent:
                agent.name = tel.agent
            self.index.update(agent.token, tel.lat, tel.lon, now)
            payload = self._detection_payload(agent.token, tel.lat, tel.lon, tel.heading, now)
        self.db.buffer_report(agent.token, self._history_row(agent.token, req, now), LatestState(
            agent.name, now, agent.mc_state, agent.hlc_state, tel if tel is not None else agent.telemetry
        ))
        operator_cmd, direction_cmd = self._take_due(agent.token, now)
        return ReportReply(
            token=agent.token, operator_cmd=operator_cmd, direction_cmd=direction_cmd, payload=payload
        )

    def _new_agent(self, name: str | None, now: float, unknown_token: str | None) -> _Agent:
        token = secrets.token_urlsafe(12)
        agent = _Agent(token, name or token, now)
        self.db.add_agent(token, agent.name, now)
        self._agents[token] = agent
        if unknown_token is not None:
            log.warning("unknown token %r (name %r): issued a new token %s", unknown_token, name, token)
        else:
            log.info("new agent %r: token %s", agent.name, token)
        return agent

    def _detection_payload(self, token: str, lat: float, lon: float, heading: float, now: float) -> Payload:
        found = self._sense(token, lat, lon, heading, now)
        detection = PeerDetection(
            detected=found.detected, count=found.count,
            nearest_range=found.nearest_range, nearest_bearing=found.nearest_bearing,
        )
        return Payload(content_type="application/json", data=detection.model_dump_json())

    def _sense(self, token: str, lat: float, lon: float, heading: float, now: float) -> sector.Detection:
        s = self.settings
        box = sector.search_box(lat, lon, heading, s.range_m, s.fov_deg)
        peers = self.index.candidates(*box, since=now - s.stale_after_s, exclude=token)
        return sector.detect(lat, lon, heading, peers, s.range_m, s.fov_deg)

    def _history_row(self, token: str, req: ReportRequest, now: float) -> tuple[object, ...] | None:
        if not self.settings.history:
            return None
        t, fb = req.telemetry, req.feedback
        tel_cols: tuple[object, ...] = (
            (t.lat, t.lon, t.alt, t.heading, t.vn, t.ve, t.vd, t.battery, int(t.armed), int(t.in_air), t.mode, t.agent)
            if t is not None else (None,) * 12
        )
        fb_cols = (fb.content_type, fb.encoding, fb.data) if fb is not None else (None, None, None)
        return (token, now, req.mc_state, req.hlc_state, *tel_cols, *fb_cols)

    def _take_due(self, token: str, now: float) -> tuple[OperatorCommand | None, DirectionCommand | None]:
        """Pop what this reply delivers (at most once), dropping commands past their TTL."""
        queue = self._queues.get(token)
        if not queue:
            return None, None
        ttl = self.settings.command_ttl_s
        cutoff = -math.inf if ttl is None else now - ttl
        done: list[tuple[int, str, str]] = []
        operator_cmd = None
        while queue.operator:
            seq, t, cmd = queue.operator.popleft()
            if t < cutoff:
                done.append((seq, token, "expired"))
                log.warning("dropped %s (seq %d) for %s: not collected within %.0f s", cmd.command, seq, token, ttl)
                continue
            done.append((seq, token, "delivered"))
            operator_cmd = cmd
            break
        direction_cmd = None
        if queue.direction is not None:
            seq, t, dcmd = queue.direction
            queue.direction = None
            if t < cutoff:
                done.append((seq, token, "expired"))
                log.warning("dropped direction (seq %d) for %s: not collected within %.0f s", seq, token, ttl)
            else:
                done.append((seq, token, "delivered"))
                direction_cmd = dcmd
        if not queue:
            del self._queues[token]
        self.db.finish_deliveries(done, now)
        return operator_cmd, direction_cmd

    # -- commands --------------------------------------------------------------------------------

    def queue(self, req: CommandRequest, now: float) -> CommandResponse:
        """Queue a command for one agent (token or name) or for every agent known now.

        Raises `UnknownTarget` when ``target`` matches no agent.
        """
        if req.target is None:
            targets = list(self._agents.values())
        elif req.target in self._agents:
            targets = [self._agents[req.target]]
        else:
            targets = [a for a in self._agents.values() if a.name == req.target]
            if not targets:
                raise UnknownTarget(req.target)
        tokens = [a.token for a in targets]
        if req.command is not None:
            kind = "operator"
            body: dict[str, object] = {"command": req.command}
            if req.altitude is not None:
                body["altitude"] = req.altitude
            replaced: list[tuple[int, str]] = []
        else:
            assert req.direction is not None  # CommandRequest validates exactly one
            kind = "direction"
            body = {"active": req.direction.active, "azimuth": req.direction.azimuth, "speed": req.direction.speed}
            replaced = [
                (q.direction[0], tok) for tok in tokens
                if (q := self._queues.get(tok)) is not None and q.direction is not None
            ]
        seq = self.db.queue_command(now, req.target, kind, body, tokens, replaced)
        # One immutable command object shared by every agent's queue; the per-agent entries are
        # built without re-validation (a broadcast to thousands of agents must not stall reports).
        queued = []
        if kind == "operator":
            op = OperatorCommand.model_validate({**body, "seq": seq})
            for agent in targets:
                self._queues.setdefault(agent.token, _Queue()).operator.append((seq, now, op))
                queued.append(QueuedCommand.model_construct(
                    token=agent.token, name=agent.name, seq=seq, operator_cmd=op, direction_cmd=None))
        else:
            dc = DirectionCommand.model_validate({**body, "seq": seq})
            for agent in targets:
                self._queues.setdefault(agent.token, _Queue()).direction = (seq, now, dc)
                queued.append(QueuedCommand.model_construct(
                    token=agent.token, name=agent.name, seq=seq, operator_cmd=None, direction_cmd=dc))
        log.info("queued %s seq %d for %s (%d agent(s))", body, seq, req.target or "every agent", len(queued))
        return CommandResponse(seq=seq, target=req.target, queued=queued)

    # -- listing and upkeep ----------------------------------------------------------------------

    @property
    def agent_count(self) -> int:
        return len(self._agents)

    def agents(self, now: float) -> list[AgentInfo]:
        """Every agent, sorted by name. Built without re-validation: the data was validated on the
        way in, and listing thousands of agents must not hold up their reports."""
        stale_before = now - self.settings.stale_after_s
        return [
            AgentInfo.model_construct(
                token=a.token, name=a.name, first_seen=a.first_seen, last_seen=a.last_seen,
                stale=a.last_seen is None or a.last_seen < stale_before,
                mc_state=a.mc_state, hlc_state=a.hlc_state, telemetry=a.telemetry,
                pending_commands=self._pending_count(a.token),
            )
            for a in sorted(self._agents.values(), key=lambda a: (a.name, a.token))
        ]

    def _pending_count(self, token: str) -> int:
        q = self._queues.get(token)
        return 0 if q is None else len(q.operator) + (q.direction is not None)

    def maintain(self, now: float) -> None:
        """Periodic upkeep: forget stale positions, so queries cost what the live agents cost."""
        self.index.sweep(now - self.settings.stale_after_s)
