"""Running the station: blocking for the CLI, or in a background thread for tests, demos and benchmarks."""

from __future__ import annotations

import logging
import socket
import threading
import time
from types import TracebackType

import uvicorn
from pydantic import ValidationError

from antalate_lcm.base.errors import AntalateError

from ._app import create_app
from ._db import StationDB
from ._settings import DEFAULT_HOST, DEFAULT_PORT, MEMORY, StationSettings

log = logging.getLogger("antalate.station")


def _config(
    settings: StationSettings, log_level: str, tls_cert: str | None = None, tls_key: str | None = None
) -> uvicorn.Config:
    # loop/http "auto" pick uvloop and httptools when installed (uvicorn[standard]): about twice the
    # reports per second of the pure-Python asyncio + h11 pair.
    # log_config=None: uvicorn's records go to the root logger, formatted like antalate's own,
    # instead of uvicorn installing handlers of its own. No access log: one line per report would
    # cost more than the report.
    return uvicorn.Config(
        create_app(settings),
        log_level=log_level.lower(),
        log_config=None,
        access_log=False,
        loop="auto",
        http="auto",
        lifespan="on",
        timeout_keep_alive=30,
        ssl_certfile=tls_cert,
        ssl_keyfile=tls_key,
    )


def _check_tls(tls_cert: str | None, tls_key: str | None) -> None:
    """Both or neither, readable, and a pair that loads: a typo fails here, not at the first client."""
    if (tls_cert is None) != (tls_key is None):
        raise AntalateError("TLS needs both a certificate (--tls-cert) and its private key (--tls-key)")
    if tls_cert is None:
        return
    import ssl

    try:
        ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(tls_cert, tls_key)
    except (OSError, ssl.SSLError) as exc:
        raise AntalateError(f"cannot use TLS certificate {tls_cert} with key {tls_key}: {exc}") from None


def _check_db(path: str) -> None:
    """Open the database once up front: a bad path or a newer schema then fails with its own message
    (`StationDBError`) instead of uvicorn's generic "Application startup failed"."""
    StationDB(path).close()


def _bind(host: str, port: int) -> socket.socket:
    """Bind before uvicorn starts, so port 0 works and a busy port is a clear error, not a log line."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # proto must say TCP explicitly: asyncio's own loop sets TCP_NODELAY on accepted connections
    # only then, and without it Nagle + delayed ACK add ~40 ms to every reply (uvloop sets it anyway).
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise AntalateError(f"station cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


def run_station(
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    db_path: str | None = None,
    range_m: float = 100.0,
    fov_deg: float = 60.0,
    *,
    stale_after_s: float = 5.0,
    command_ttl_s: float | None = 60.0,
    history_retention_s: float | None = 24 * 3600.0,
    log_level: str = "info",
    settings: StationSettings | None = None,
    tls_cert: str | None = None,
    tls_key: str | None = None,
) -> None:
    """Serve the station until SIGINT/SIGTERM (what ``antalate station`` calls).

    ``db_path`` None means the per-user default (`default_db_path`); ``":memory:"`` keeps nothing.
    The other parameters are `StationSettings` fields; ``settings``, when given, replaces them all
    (what a station config file gives). ``tls_cert``/``tls_key`` (PEM files) serve HTTPS. Raises
    `AntalateError` for a port that cannot be bound, a database that cannot be used, a TLS pair that
    does not load or parameters out of range.
    """
    if settings is None:
        fields: dict[str, object] = {
            "range_m": range_m,
            "fov_deg": fov_deg,
            "stale_after_s": stale_after_s,
            "command_ttl_s": command_ttl_s,
            "history_retention_s": history_retention_s,
        }
        if db_path is not None:
            fields["db_path"] = db_path
        try:
            settings = StationSettings.model_validate(fields)
        except ValidationError as exc:
            raise AntalateError(f"invalid station parameters: {exc}") from None
    _check_tls(tls_cert, tls_key)
    _check_db(settings.db_path)
    sock = _bind(host, port)
    actual = sock.getsockname()[1]
    scheme = "https" if tls_cert else "http"
    log.info("station listening on %s://%s:%d (database %s)", scheme, host, actual, settings.db_path)
    if not settings.api_keys:
        log.warning(
            "no API keys configured: /api/agents and /api/commands answer 401 (antalate station-key api)"
        )
    if settings.registration_key is None:
        log.warning(
            "no registration key: any host that reaches the station can register an agent "
            "(antalate station-key registration)"
        )
    server = uvicorn.Server(_config(settings, log_level, tls_cert, tls_key))
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
    if not server.started:
        raise AntalateError(f"station did not start (database {settings.db_path}); see the log above")


class StationServer:
    """The station in a background thread of this process, e.g. ``with StationServer(s) as srv: srv.url``.

    Port 0 (the default) picks a free port. Used by the tests, the benchmark and the demo; a real
    deployment runs ``antalate station``.
    """

    def __init__(
        self,
        settings: StationSettings | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        log_level: str = "warning",
        *,
        tls_cert: str | None = None,
        tls_key: str | None = None,
    ) -> None:
        self.settings = settings if settings is not None else StationSettings()
        if self.settings.db_path != MEMORY:
            _check_db(self.settings.db_path)
        _check_tls(tls_cert, tls_key)
        self.host = host
        self.scheme = "https" if tls_cert else "http"
        self._sock = _bind(host, port)
        self.port: int = self._sock.getsockname()[1]
        self._server = uvicorn.Server(_config(self.settings, log_level, tls_cert, tls_key))
        self._thread = threading.Thread(target=self._run, name="station-server", daemon=True)
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"

    def _run(self) -> None:
        try:
            # Server.run sets up the configured loop (uvloop when installed) and skips signal
            # handling outside the main thread, so it is safe here.
            self._server.run(sockets=[self._sock])
        except BaseException as exc:  # surfaced by start()
            self._error = exc

    def start(self, timeout: float = 10.0) -> StationServer:
        """Start serving; returns once the app has started (database open), raises if it could not."""
        self._thread.start()
        deadline = time.monotonic() + timeout
        while not self._server.started and self._thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.005)
        if not self._server.started:
            self.stop()
            reason = repr(self._error) if self._error is not None else "see the log"
            raise AntalateError(f"station did not start on {self.url}: {reason}")
        return self

    def stop(self, timeout: float = 10.0) -> None:
        """Graceful stop: in-flight requests finish, buffered history is written, the database closed."""
        self._server.should_exit = True
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._sock.close()

    def __enter__(self) -> StationServer:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, _tb: TracebackType | None
    ) -> None:
        self.stop()
