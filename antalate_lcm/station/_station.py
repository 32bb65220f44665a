"""The station's state and rules, independent of HTTP: agents, tokens, the command queue, sensing.

Every method takes the current time as an argument (no clock of its own) and is called from one
thread, the server's event loop, so the in-memory state needs no locks. The database is the
source of truth for tokens and commands (written before a reply depends on them); the in-memory
copies exist so that a report costs dictionary look-ups, not queries.
"""

from __future__ import annotations

import logging
import math
import re
import secrets
from collections import deque
from dataclasses import dataclass, field

from antalate_lcm.base.errors import Refused, UnknownTarget
from antalate_lcm.base.ratelimit import TokenBucket

from . import sector
from ._auth import check_registration, new_token, sha256_hex
from ._db import AgentRow, LatestState, StationDB
from ._models import (
    AGENT_NAME,
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


def _bucket(rate: float | None, burst: int) -> TokenBucket | None:
    return TokenBucket(rate, burst) if rate is not None else None


@dataclass(slots=True)
class _Agent:
    id: str
    token_hash: str
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
        self._by_hash: dict[str, _Agent] = {}
        self._by_name: dict[str, _Agent] = {}
        self._queues: dict[str, _Queue] = {}
        self._nonces: dict[str, float] = {}  # registration nonces seen -> when they may be forgotten
        limits = settings.rate_limits
        self._registrations = _bucket(
            limits.registrations_per_minute / 60.0 if limits.registrations_per_minute else None,
            limits.registration_burst,
        )
        self._reports = _bucket(limits.reports_per_second, limits.report_burst)
        self._addresses = _bucket(limits.address_reports_per_second, limits.address_burst)
        for row in db.load_agents():
            self._adopt(row)
        for p in db.load_pending():
            queue = self._queues.setdefault(p.agent_id, _Queue())
            # A signed command's body holds the operator's seq, which wins over the station's.
            if p.kind == "operator":
                queue.operator.append((p.seq, p.t, OperatorCommand.model_validate({"seq": p.seq, **p.body})))
            else:
                queue.direction = (p.seq, p.t, DirectionCommand.model_validate({"seq": p.seq, **p.body}))
        log.info(
            "station: %d agent(s) and %d pending command(s) from %s; range %.1f m, field of view %.1f°",
            len(self._agents),
            sum(len(q.operator) + (q.direction is not None) for q in self._queues.values()),
            db.path,
            settings.range_m,
            settings.fov_deg,
        )

    def _adopt(self, row: AgentRow) -> None:
        agent = _Agent(
            row.id,
            row.token_hash,
            row.name,
            row.first_seen,
            row.last_seen,
            row.mc_state,
            row.hlc_state,
            row.telemetry,
        )
        self._agents[row.id] = self._by_hash[row.token_hash] = self._by_name[row.name] = agent
        if row.telemetry is not None and row.last_seen is not None:
            self.index.update(row.id, row.telemetry.lat, row.telemetry.lon, row.last_seen)

    # -- reports ---------------------------------------------------------------------------------

    def admit(self, address: str, now: float) -> None:
        """The per-source-address limit, before a request is even parsed. Raises `Refused` (429)."""
        if self._addresses is not None:
            wait = self._addresses.take(address, now)
            if wait:
                raise Refused(429, f"too many requests from {address}", wait)

    def report(self, req: ReportRequest, now: float, address: str = "") -> ReportReply:
        """Record one report and build its reply: token, due commands, peer detection.

        Raises `Refused`: 401 unknown token or missing/invalid registration proof, 409 a name that
        is taken, 429 over a rate limit.
        """
        tel = req.telemetry
        claimed = req.agent or (tel.agent if tel is not None and tel.agent else None)
        if req.token is None:
            agent, token = self._register(req, claimed, now, address)
        else:
            found = self._by_hash.get(sha256_hex(req.token))
            if found is None:
                raise Refused(401, "unknown token: register again (a report without a token)")
            agent, token = found, req.token
            if claimed is not None and claimed != agent.name:
                raise Refused(409, f"this token belongs to {agent.name!r}, not {claimed!r}")
            if self._reports is not None:
                wait = self._reports.take(agent.id, now)
                if wait:
                    raise Refused(429, f"{agent.name} reports too often", wait)
        agent.last_seen = now
        if req.mc_state is not None:
            agent.mc_state = req.mc_state
        if req.hlc_state is not None:
            agent.hlc_state = req.hlc_state
        payload = None
        if tel is not None:
            agent.telemetry = tel
            self.index.update(agent.id, tel.lat, tel.lon, now)
            payload = self._detection_payload(agent.id, tel.lat, tel.lon, tel.heading, now)
        self.db.buffer_report(
            agent.id,
            self._history_row(agent.id, req, now),
            LatestState(
                agent.name, now, agent.mc_state, agent.hlc_state, tel if tel is not None else agent.telemetry
            ),
        )
        operator_cmd, direction_cmd = self._take_due(agent.id, now)
        return ReportReply(
            token=token, operator_cmd=operator_cmd, direction_cmd=direction_cmd, payload=payload
        )

    def _register(self, req: ReportRequest, name: str | None, now: float, address: str) -> tuple[_Agent, str]:
        """First contact: a new agent, or a proven one taking its own name back with a new token."""
        if self._registrations is not None:
            wait = self._registrations.take(address, now)
            if wait:
                raise Refused(429, f"too many registrations from {address}", wait)
        if name is not None and not re.fullmatch(AGENT_NAME, name):
            raise Refused(
                422, f"agent name {name[:70]!r}: letters, digits, '-', '_' and '.' only, at most 64"
            )
        proven = self._check_proof(req, name, now)
        existing = self._by_name.get(name) if name is not None else None
        token = new_token()
        token_hash = sha256_hex(token)
        if existing is not None:
            if not proven:
                raise Refused(
                    409,
                    f"the name {name!r} is registered: report with its token, or register with proof of the "
                    "swarm key (docs/station-protocol.md, Tokens)",
                )
            self.db.set_token_hash(existing.id, token_hash)
            del self._by_hash[existing.token_hash]
            existing.token_hash = token_hash
            self._by_hash[token_hash] = existing
            log.info(
                "agent %r re-registered with proof from %s: new token, the old one is void", name, address
            )
            return existing, token
        agent_id = secrets.token_hex(6)
        while agent_id in self._agents or agent_id in self._by_name:  # an id also names an anonymous agent
            agent_id = secrets.token_hex(6)
        agent = _Agent(agent_id, token_hash, name or agent_id, now)
        self.db.add_agent(agent.id, token_hash, agent.name, now)
        self._agents[agent.id] = self._by_hash[token_hash] = self._by_name[agent.name] = agent
        log.info(
            "new agent %r (id %s) from %s%s", agent.name, agent.id, address, " with proof" if proven else ""
        )
        return agent, token

    def _check_proof(self, req: ReportRequest, name: str | None, now: float) -> bool:
        """True when the registration proves the swarm key; raises 401 when the station needs a proof
        and this one is missing or wrong. Without a registration key, proofs are not checked (False)."""
        key = self.settings.registration_key
        if key is None:
            return False
        reg = req.registration
        if reg is None:
            raise Refused(
                401, "this station registers only agents that prove the swarm key ([security] swarm_key)"
            )
        if name is None:
            raise Refused(401, 'a registration proof needs the agent\'s name ("agent")')
        window = self.settings.registration_window_s
        problem = check_registration(key, name, reg.utime, reg.nonce, reg.mac, now, window)
        if problem is not None:
            raise Refused(401, problem)
        if reg.nonce in self._nonces:
            raise Refused(401, "registration proof already used (replayed)")
        self._nonces[reg.nonce] = now + 2 * window
        return True

    def _detection_payload(self, token: str, lat: float, lon: float, heading: float, now: float) -> Payload:
        found = self._sense(token, lat, lon, heading, now)
        detection = PeerDetection(
            detected=found.detected,
            count=found.count,
            nearest_range=found.nearest_range,
            nearest_bearing=found.nearest_bearing,
        )
        return Payload(content_type="application/json", data=detection.model_dump_json())

    def _sense(self, token: str, lat: float, lon: float, heading: float, now: float) -> sector.Detection:
        s = self.settings
        box = sector.search_box(lat, lon, heading, s.range_m, s.fov_deg)
        peers = self.index.candidates(*box, since=now - s.stale_after_s, exclude=token)
        return sector.detect(lat, lon, heading, peers, s.range_m, s.fov_deg)

    def _history_row(self, agent_id: str, req: ReportRequest, now: float) -> tuple[object, ...] | None:
        if not self.settings.history:
            return None
        t, fb = req.telemetry, req.feedback
        tel_cols: tuple[object, ...] = (
            (
                t.lat,
                t.lon,
                t.alt,
                t.heading,
                t.vn,
                t.ve,
                t.vd,
                t.battery,
                int(t.armed),
                int(t.in_air),
                t.mode,
                t.agent,
            )
            if t is not None
            else (None,) * 12
        )
        fb_cols = (fb.content_type, fb.encoding, fb.data) if fb is not None else (None, None, None)
        return (agent_id, now, req.mc_state, req.hlc_state, *tel_cols, *fb_cols)

    def _take_due(self, agent_id: str, now: float) -> tuple[OperatorCommand | None, DirectionCommand | None]:
        """Pop what this reply delivers (at most once), dropping commands past their TTL."""
        queue = self._queues.get(agent_id)
        if not queue:
            return None, None
        ttl = self.settings.command_ttl_s
        cutoff = -math.inf if ttl is None else now - ttl
        done: list[tuple[int, str, str]] = []
        operator_cmd = None
        while queue.operator:
            seq, t, cmd = queue.operator.popleft()
            if t < cutoff:
                done.append((seq, agent_id, "expired"))
                log.warning(
                    "dropped %s (seq %d) for %s: not collected within %.0f s", cmd.command, seq, agent_id, ttl
                )
                continue
            done.append((seq, agent_id, "delivered"))
            operator_cmd = cmd
            break
        direction_cmd = None
        if queue.direction is not None:
            seq, t, dcmd = queue.direction
            queue.direction = None
            if t < cutoff:
                done.append((seq, agent_id, "expired"))
                log.warning(
                    "dropped direction (seq %d) for %s: not collected within %.0f s", seq, agent_id, ttl
                )
            else:
                done.append((seq, agent_id, "delivered"))
                direction_cmd = dcmd
        if not queue:
            del self._queues[agent_id]
        self.db.finish_deliveries(done, now)
        return operator_cmd, direction_cmd

    # -- commands --------------------------------------------------------------------------------

    def queue(self, req: CommandRequest, now: float) -> CommandResponse:
        """Queue a command for one agent (id or name) or for every agent known now.

        A signed command is stored and forwarded field for field (the agent verifies its MAC), to
        the agent its signed target names ("" = every agent). Raises `UnknownTarget` when the target
        matches no agent, `Refused` (422) for an unsigned command when the agents hold a swarm key.
        """
        if not req.signed and self.settings.registration_key is not None:
            raise Refused(
                422,
                "this station's agents hold a swarm key and drop unsigned commands: sign it "
                "(antalate command --swarm-key-file, or antalate_lcm.station.client.StationClient)",
            )
        target = req.target
        signed = req.operator_cmd or req.direction_cmd
        if signed is not None:
            target = signed.target or None
        if target is None:
            targets = list(self._agents.values())
        elif signed is None and target in self._agents:
            targets = [self._agents[target]]
        elif target in self._by_name:
            targets = [self._by_name[target]]
        else:
            raise UnknownTarget(target)
        agent_ids = [a.id for a in targets]
        body: dict[str, object]
        if req.operator_cmd is not None:
            kind = "operator"
            body = req.operator_cmd.model_dump()
            replaced: list[tuple[int, str]] = []
        elif req.command is not None:
            kind = "operator"
            body = {"command": req.command}
            if req.altitude is not None:
                body["altitude"] = req.altitude
            replaced = []
        else:
            kind = "direction"
            if req.direction_cmd is not None:
                body = req.direction_cmd.model_dump()
            else:
                assert req.direction is not None  # CommandRequest validates exactly one
                body = {
                    "active": req.direction.active,
                    "azimuth": req.direction.azimuth,
                    "speed": req.direction.speed,
                }
            replaced = [
                (q.direction[0], aid)
                for aid in agent_ids
                if (q := self._queues.get(aid)) is not None and q.direction is not None
            ]
        seq = self.db.queue_command(now, target, kind, body, agent_ids, replaced)
        # One immutable command object shared by every agent's queue; the per-agent entries are
        # built without re-validation (a broadcast to thousands of agents must not stall reports).
        queued = []
        if kind == "operator":
            op = OperatorCommand.model_validate({"seq": seq, **body})
            for agent in targets:
                self._queues.setdefault(agent.id, _Queue()).operator.append((seq, now, op))
                queued.append(
                    QueuedCommand.model_construct(
                        id=agent.id, name=agent.name, seq=seq, operator_cmd=op, direction_cmd=None
                    )
                )
        else:
            dc = DirectionCommand.model_validate({"seq": seq, **body})
            for agent in targets:
                self._queues.setdefault(agent.id, _Queue()).direction = (seq, now, dc)
                queued.append(
                    QueuedCommand.model_construct(
                        id=agent.id, name=agent.name, seq=seq, operator_cmd=None, direction_cmd=dc
                    )
                )
        shown = {k: v for k, v in body.items() if k != "mac"}
        log.info(
            "queued %s%s seq %d for %s (%d agent(s))",
            "signed " if signed else "",
            shown,
            seq,
            target or "every agent",
            len(queued),
        )
        return CommandResponse(seq=seq, target=target, queued=queued)

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
                id=a.id,
                name=a.name,
                first_seen=a.first_seen,
                last_seen=a.last_seen,
                stale=a.last_seen is None or a.last_seen < stale_before,
                mc_state=a.mc_state,
                hlc_state=a.hlc_state,
                telemetry=a.telemetry,
                pending_commands=self._pending_count(a.id),
            )
            for a in sorted(self._agents.values(), key=lambda a: (a.name, a.id))
        ]

    def _pending_count(self, token: str) -> int:
        q = self._queues.get(token)
        return 0 if q is None else len(q.operator) + (q.direction is not None)

    def maintain(self, now: float) -> None:
        """Periodic upkeep: forget stale positions, so queries cost what the live agents cost; forget
        full rate-limit buckets and registration nonces past their window."""
        self.index.sweep(now - self.settings.stale_after_s)
        for bucket in (self._registrations, self._reports, self._addresses):
            if bucket is not None:
                bucket.sweep(now)
        expired = [n for n, until in self._nonces.items() if until < now]
        for n in expired:
            del self._nonces[n]
