"""SQLite persistence: agents, the command queue and the report history.

Two kinds of writes, treated differently on purpose:

* **Rare and must survive a crash** — a new agent's token, a queued command, a delivery. These are
  written synchronously, each in its own transaction, before the HTTP reply that depends on them.
* **One per report** — the history row and the agent's latest state. At thousands of reports a
  second a transaction each would make SQLite (fsync, WAL checkpoints) the station's bottleneck,
  so they are appended to an in-memory buffer and a writer thread stores them in one transaction
  every ``flush_s``. A crash loses at most that interval of history; tokens and commands are never
  in the buffer.

One connection, guarded by a lock, serves both the event loop and the writer thread: SQLite
serialises writers anyway, and the event loop's writes are rare and short.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from antalate_lcm.base.errors import StationDBError

from ._models import Telemetry
from ._settings import MEMORY

log = logging.getLogger("antalate.station")

SCHEMA_VERSION = 2
_PRUNE_EVERY_S = 60.0

_SCHEMA = """
CREATE TABLE IF NOT EXISTS agents (
    id          TEXT PRIMARY KEY,               -- public: listed, a command may target it
    token_hash  TEXT NOT NULL UNIQUE,           -- hex SHA-256 of the agent's token (never the token)
    name        TEXT NOT NULL UNIQUE,           -- claimed at registration; never taken over
    first_seen  REAL NOT NULL,
    last_seen   REAL,
    mc_state    TEXT,
    hlc_state   TEXT,
    telemetry   TEXT            -- JSON object of the latest telemetry (wire field names), NULL = none yet
);
CREATE TABLE IF NOT EXISTS reports (
    id                INTEGER PRIMARY KEY,
    agent_id          TEXT NOT NULL,
    t                 REAL NOT NULL,  -- station clock, UNIX seconds
    mc_state          TEXT,
    hlc_state         TEXT,
    lat REAL, lon REAL, alt REAL, heading REAL, vn REAL, ve REAL, vd REAL, battery REAL,
    armed INTEGER, in_air INTEGER, mode TEXT, agent TEXT,
    feedback_type     TEXT,
    feedback_encoding TEXT,
    feedback_data     TEXT
);
CREATE INDEX IF NOT EXISTS reports_by_agent ON reports (agent_id, t);
CREATE INDEX IF NOT EXISTS reports_by_time ON reports (t);
CREATE TABLE IF NOT EXISTS commands (
    seq     INTEGER PRIMARY KEY AUTOINCREMENT,  -- never reused, so an MC never mistakes a new command for a duplicate
    t       REAL NOT NULL,
    target  TEXT,                               -- as requested; NULL = every agent
    kind    TEXT NOT NULL CHECK (kind IN ('operator', 'direction')),
    body    TEXT NOT NULL                       -- JSON of the command without the station's seq (a signed
                                                -- command keeps the operator's header, MAC included)
);
CREATE TABLE IF NOT EXISTS deliveries (
    seq       INTEGER NOT NULL REFERENCES commands (seq),
    agent_id  TEXT NOT NULL REFERENCES agents (id),
    state     TEXT NOT NULL CHECK (state IN ('pending', 'delivered', 'replaced', 'expired')),
    t_done    REAL,
    PRIMARY KEY (agent_id, seq)
);
CREATE INDEX IF NOT EXISTS deliveries_pending ON deliveries (state) WHERE state = 'pending';
"""

_REPORT_COLUMNS = (
    "agent_id, t, mc_state, hlc_state, lat, lon, alt, heading, vn, ve, vd, battery, armed, in_air, mode, agent, "
    "feedback_type, feedback_encoding, feedback_data"
)
_INSERT_REPORT = f"INSERT INTO reports ({_REPORT_COLUMNS}) VALUES ({', '.join('?' * 19)})"

ReportRow = tuple[object, ...]
"""One ``reports`` row in `_REPORT_COLUMNS` order."""


@dataclass(frozen=True, slots=True)
class AgentRow:
    id: str
    token_hash: str
    name: str
    first_seen: float
    last_seen: float | None
    mc_state: str | None
    hlc_state: str | None
    telemetry: Telemetry | None


@dataclass(frozen=True, slots=True)
class PendingRow:
    seq: int
    agent_id: str
    t: float
    kind: str
    body: dict[str, object]


@dataclass(slots=True)
class LatestState:
    """An agent's newest report, written to ``agents`` at the next flush (only the newest counts)."""

    name: str
    last_seen: float
    mc_state: str | None
    hlc_state: str | None
    telemetry: Telemetry | None


class StationDB:
    """The station's tables behind a small API; see the module docstring for the write policy."""

    def __init__(self, path: str) -> None:
        self.path = path
        if path != MEMORY:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        try:
            self._conn = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        except sqlite3.Error as exc:
            raise StationDBError(f"cannot open {path} as the station database: {exc}") from exc
        try:
            self._init_schema()
        except (sqlite3.Error, StationDBError) as exc:
            self._conn.close()
            if isinstance(exc, StationDBError):
                raise
            raise StationDBError(f"cannot use {path} as the station database: {exc}") from exc
        self._lock = threading.Lock()
        self._buffer_lock = threading.Lock()
        self._rows: list[ReportRow] = []
        self._latest: dict[str, LatestState] = {}
        self._writer: threading.Thread | None = None
        self._stop = threading.Event()

    def _init_schema(self) -> None:
        conn = self._conn
        if self.path != MEMORY:
            conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
        conn.execute("PRAGMA busy_timeout=5000")
        conn.execute("PRAGMA foreign_keys=ON")
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            raise StationDBError(
                f"{self.path} has station schema version {version}; this antalate knows up to {SCHEMA_VERSION}"
            )
        if version == 1:
            self._retire_v1()
        conn.executescript(_SCHEMA)
        conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

    def _retire_v1(self) -> None:
        """Version 1 kept agents' tokens in clear and listed them to anyone: they cannot be trusted.
        Its tables are kept under ``*_v1`` names (the history stays readable) and every agent
        registers afresh."""
        conn = self._conn
        conn.execute("PRAGMA foreign_keys=OFF")
        try:
            conn.execute("BEGIN IMMEDIATE")
            for table in ("deliveries", "commands", "reports", "agents"):
                conn.execute(f"ALTER TABLE {table} RENAME TO {table}_v1")
            for index in ("reports_by_agent", "reports_by_time", "deliveries_pending"):
                conn.execute(f"DROP INDEX IF EXISTS {index}")
            conn.execute("COMMIT")
        except sqlite3.Error:
            conn.execute("ROLLBACK")
            raise
        finally:
            conn.execute("PRAGMA foreign_keys=ON")
        log.warning(
            "%s was a version-1 station database (tokens in clear): its tables are kept as *_v1 and every "
            "agent registers again",
            self.path,
        )

    # -- startup ---------------------------------------------------------------------------------

    def load_agents(self) -> list[AgentRow]:
        with self._lock:
            rows = self._conn.execute(
                "SELECT id, token_hash, name, first_seen, last_seen, mc_state, hlc_state, telemetry FROM agents"
            ).fetchall()
        return [
            AgentRow(aid, th, name, first, last, mc, hlc, Telemetry.model_validate_json(tel) if tel else None)
            for aid, th, name, first, last, mc, hlc, tel in rows
        ]

    def load_pending(self) -> list[PendingRow]:
        with self._lock:
            rows = self._conn.execute(
                "SELECT c.seq, d.agent_id, c.t, c.kind, c.body FROM deliveries d JOIN commands c USING (seq) "
                "WHERE d.state = 'pending' ORDER BY c.seq"
            ).fetchall()
        return [PendingRow(seq, aid, t, kind, json.loads(body)) for seq, aid, t, kind, body in rows]

    # -- synchronous writes ----------------------------------------------------------------------

    def add_agent(self, agent_id: str, token_hash: str, name: str, t: float) -> None:
        with self._lock:
            self._conn.execute(
                "INSERT INTO agents (id, token_hash, name, first_seen) VALUES (?, ?, ?, ?)",
                (agent_id, token_hash, name, t),
            )

    def set_token_hash(self, agent_id: str, token_hash: str) -> None:
        """A re-registration (with proof) replaces the agent's token; the old one stops working."""
        with self._lock:
            self._conn.execute("UPDATE agents SET token_hash = ? WHERE id = ?", (token_hash, agent_id))

    def queue_command(
        self,
        t: float,
        target: str | None,
        kind: str,
        body: dict[str, object],
        agent_ids: Sequence[str],
        replaced: Iterable[tuple[int, str]] = (),
    ) -> int:
        """Store a command and one pending delivery per agent in one transaction; returns its seq.

        ``replaced`` are (seq, agent id) deliveries the new command supersedes (an older direction).
        """
        with self._lock, self._transaction():
            cur = self._conn.execute(
                "INSERT INTO commands (t, target, kind, body) VALUES (?, ?, ?, ?)",
                (t, target, kind, json.dumps(body)),
            )
            seq = int(cur.lastrowid or 0)
            self._conn.executemany(
                "UPDATE deliveries SET state = 'replaced', t_done = ? WHERE seq = ? AND agent_id = ?",
                [(t, s, aid) for s, aid in replaced],
            )
            self._conn.executemany(
                "INSERT INTO deliveries (seq, agent_id, state) VALUES (?, ?, 'pending')",
                [(seq, aid) for aid in agent_ids],
            )
        return seq

    def finish_deliveries(self, done: Iterable[tuple[int, str, str]], t: float) -> None:
        """Mark (seq, agent id, state) deliveries as delivered/expired: they leave the queue for good."""
        with self._lock, self._transaction():
            self._conn.executemany(
                "UPDATE deliveries SET state = ?, t_done = ? WHERE seq = ? AND agent_id = ? AND state = 'pending'",
                [(state, t, seq, aid) for seq, aid, state in done],
            )

    def _transaction(self) -> _Transaction:
        return _Transaction(self._conn)

    # -- buffered writes -------------------------------------------------------------------------

    def buffer_report(self, agent_id: str, row: ReportRow | None, latest: LatestState) -> None:
        """Queue a history row (None = history off) and the agent's newest state; no I/O here."""
        with self._buffer_lock:
            if row is not None:
                self._rows.append(row)
            self._latest[agent_id] = latest

    def flush(self) -> int:
        """Write everything buffered so far in one transaction; returns the number of history rows."""
        with self._buffer_lock:
            rows, self._rows = self._rows, []
            latest, self._latest = self._latest, {}
        if not rows and not latest:
            return 0
        updates = [
            (
                s.name,
                s.last_seen,
                s.mc_state,
                s.hlc_state,
                s.telemetry.model_dump_json() if s.telemetry is not None else None,
                aid,
            )
            for aid, s in latest.items()
        ]
        with self._lock, self._transaction():
            self._conn.executemany(_INSERT_REPORT, rows)
            self._conn.executemany(
                "UPDATE agents SET name = ?, last_seen = ?, mc_state = ?, hlc_state = ?, telemetry = ? "
                "WHERE id = ?",
                updates,
            )
        return len(rows)

    def prune_history(self, before: float) -> int:
        with self._lock:
            cur = self._conn.execute("DELETE FROM reports WHERE t < ?", (before,))
        return cur.rowcount

    def start_writer(
        self, flush_s: float, retention_s: float | None = None, clock: Callable[[], float] = time.time
    ) -> None:
        """Flush from a background thread every ``flush_s`` so the event loop never waits on disk.

        The same thread deletes history older than ``retention_s`` once a minute: a large DELETE
        would otherwise stall the replies of every agent for the milliseconds it takes.
        """
        self._writer = threading.Thread(
            target=self._write_loop, args=(flush_s, retention_s, clock), name="station-db", daemon=True
        )
        self._writer.start()

    def _write_loop(self, flush_s: float, retention_s: float | None, clock: Callable[[], float]) -> None:
        next_prune = clock()
        while not self._stop.wait(flush_s):
            try:
                self.flush()
                if retention_s is not None and clock() >= next_prune:
                    next_prune = clock() + _PRUNE_EVERY_S
                    pruned = self.prune_history(clock() - retention_s)
                    if pruned:
                        log.info("deleted %d history row(s) older than %.0f s", pruned, retention_s)
            except sqlite3.Error:
                # Keep serving: the history is best-effort (this batch is lost, and said so); the
                # tokens and commands the station depends on never go through this path.
                log.exception("writing the report history to %s failed", self.path)

    def close(self) -> None:
        """Stop the writer, write what is buffered, close the file."""
        self._stop.set()
        if self._writer is not None:
            self._writer.join()
        try:
            self.flush()
        finally:
            with self._lock:
                self._conn.close()


class _Transaction:
    """BEGIN IMMEDIATE … COMMIT/ROLLBACK for a connection in autocommit mode."""

    def __init__(self, conn: sqlite3.Connection) -> None:
        self._conn = conn

    def __enter__(self) -> None:
        self._conn.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type: object, exc: object, _tb: object) -> None:
        self._conn.execute("ROLLBACK" if exc_type is not None else "COMMIT")
