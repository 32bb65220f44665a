"""``antalate tui --web``: the same Textual console, in a browser on any machine that reaches it.

textual-serve runs one console process per browser tab (``python -m operator_tui``) and relays its
terminal over a WebSocket to xterm.js. What antalate adds to the stock server:

* **Nothing from the internet at run time.** textual-serve's page loads its web font from a CDN; our
  copy of the page (``web_templates/app_index.html``) serves it from textual-serve's own static
  folder, and xterm.js is bundled in its ``textual.js``. A field laptop has no internet.
* **The operator credential.** With ``--keys FILE`` (a station config, or any TOML file with its
  ``[[api_keys]]`` tables) the page asks for an *operator* API key (the station's, docs/security.md)
  and gives the browser a session cookie; a ``read-only`` key cannot fly, so it is refused. A
  console that listens beyond loopback without keys is refused unless ``--no-auth`` says so:
  whoever reaches the page commands the swarm.
* **WebSocket origin check**, so another web site open in the operator's browser cannot drive the
  console through the cookie.
* **One name per tab** (``operator-web1``, ``operator-web2``, ...): two consoles under one name would
  trip the agents' per-sender replay guard (docs/security.md).
"""

from __future__ import annotations

import argparse
import asyncio
import hmac
import ipaddress
import itertools
import logging
import secrets
import shlex
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from antalate_lcm.errors import AntalateError

if TYPE_CHECKING:
    from aiohttp import web

    from antalate_lcm.station._settings import ApiKey

log = logging.getLogger("antalate.tui.web")

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
SESSION_COOKIE = "antalate_console"
SESSION_TTL_S = 12 * 3600.0
TEMPLATES = Path(__file__).resolve().parent / "web_templates"


# ------------------------------------------------------------------------------------------ access
@dataclass(frozen=True)
class Refusal:
    status: int
    text: str


@dataclass
class ConsoleAccess:
    """Operator API keys (as SHA-256) and the browser sessions they opened. Pure: the clock is passed.

    A session token is random and kept only in memory: restarting the server signs everyone out,
    which is what an operator expects of a console that was restarted.
    """

    keys: tuple[ApiKey, ...]
    ttl_s: float = SESSION_TTL_S
    sessions: dict[str, tuple[str, float]] = field(default_factory=dict)

    def login(self, key: str, now: float) -> tuple[str, str] | Refusal:
        """A new session (token, holder's name) for a valid operator key, else why not."""
        from antalate_lcm.station._auth import sha256_hex

        digest = sha256_hex(key.strip())
        match = next((k for k in self.keys if hmac.compare_digest(k.sha256, digest)), None)
        if match is None:
            return Refusal(401, "Unknown API key.")
        if match.role != "operator":
            return Refusal(
                403,
                f"The key of {match.name!r} is {match.role}: the console commands vehicles, "
                "it needs an operator key.",
            )
        self._expire(now)
        token = secrets.token_urlsafe(32)
        self.sessions[token] = (match.name, now + self.ttl_s)
        return token, match.name

    def holder(self, token: str | None, now: float) -> str | None:
        """The name behind a live session token, or None."""
        if not token:
            return None
        entry = self.sessions.get(token)
        if entry is None or entry[1] < now:
            self.sessions.pop(token, None)
            return None
        return entry[0]

    def _expire(self, now: float) -> None:
        for token in [t for t, (_, until) in self.sessions.items() if until < now]:
            del self.sessions[token]


def load_keys(path: str) -> tuple[ApiKey, ...]:
    """The ``[[api_keys]]`` of a station config (or of a file holding only those tables)."""
    from antalate_lcm.station._file import load_station_file

    keys = load_station_file(path).settings.api_keys
    if not any(k.role == "operator" for k in keys):
        raise AntalateError(f'{path} has no [[api_keys]] entry with role = "operator": nobody could sign in')
    return keys


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def same_origin(origin: str | None, scheme: str, host: str) -> bool:
    """Browsers send Origin with every WebSocket; a client without one cannot be a cross-site page."""
    return origin is None or origin == f"{scheme}://{host}"


def console_command(config: str | None, name: str) -> str:
    """The shell command textual-serve runs for one browser tab."""
    args = [
        sys.executable,
        "-m",
        "operator_tui",
        *([str(Path(config).resolve())] if config else []),
        "--name",
        name,
    ]
    return shlex.join(args)


# ------------------------------------------------------------------------------------------ server
def make_server(
    config: str | None,
    *,
    name: str,
    host: str,
    port: int,
    access: ConsoleAccess | None,
    clock: Callable[[], float] = time.time,
) -> Any:
    """The textual-serve server with antalate's page, credential and per-tab names."""
    import aiohttp_jinja2
    import jinja2
    import textual_serve
    from aiohttp import WSMsgType, web
    from textual_serve.app_service import AppService
    from textual_serve.server import Server, to_int

    statics = Path(textual_serve.__file__).resolve().parent / "static"
    tabs = itertools.count(1)

    class ConsoleServer(Server):
        async def _make_app(self) -> web.Application:
            app = web.Application(middlewares=[self._guard])
            aiohttp_jinja2.setup(app, loader=jinja2.FileSystemLoader(TEMPLATES), autoescape=True)
            app.add_routes(
                [
                    web.get("/", self.handle_index, name="index"),
                    web.get("/login", self.handle_login_page, name="login"),
                    web.post("/login", self.handle_login),
                    web.get("/ws", self.handle_websocket, name="websocket"),
                    web.static("/static", statics, show_index=False, name="static"),
                ]
            )
            app.on_startup.append(self.on_startup)
            return app

        @web.middleware
        async def _guard(
            self, request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
        ) -> web.StreamResponse:
            if access is None or request.path == "/login" or request.path.startswith("/static/"):
                return await handler(request)
            if access.holder(request.cookies.get(SESSION_COOKIE), clock()) is None:
                if request.path == "/":
                    raise web.HTTPSeeOther("login")
                raise web.HTTPUnauthorized(text="sign in first (GET /login)")
            return await handler(request)

        def _page_context(self, request: web.Request) -> dict[str, Any]:
            # URLs from the request's own Host: the page works from any machine, whatever we bound to.
            scheme = "wss" if request.secure else "ws"
            return {
                "font_size": to_int(request.query.get("fontsize", "16"), 16),
                "app_websocket_url": f"{scheme}://{request.host}/ws",
                "config": {"static": {"url": "static/"}},
                "application": {"name": self.title},
                "ping_url": None,
            }

        async def handle_index(self, request: web.Request) -> web.Response:
            return aiohttp_jinja2.render_template("app_index.html", request, self._page_context(request))

        async def handle_login_page(self, request: web.Request) -> web.Response:
            if access is None:
                raise web.HTTPSeeOther("/")
            return aiohttp_jinja2.render_template("login.html", request, {"problem": None})

        async def handle_login(self, request: web.Request) -> web.Response:
            if access is None:
                raise web.HTTPSeeOther("/")
            form = await request.post()
            result = access.login(str(form.get("key", "")), clock())
            if isinstance(result, Refusal):
                log.warning("console sign-in refused from %s: %s", request.remote, result.text)
                response = aiohttp_jinja2.render_template("login.html", request, {"problem": result.text})
                response.set_status(result.status)
                return response
            token, holder = result
            log.info("console signed in from %s with the key of %r", request.remote, holder)
            response = web.HTTPSeeOther("/")
            response.set_cookie(
                SESSION_COOKIE,
                token,
                max_age=int(access.ttl_s),
                httponly=True,
                samesite="Strict",
                secure=request.secure,
                path="/",
            )
            raise response

        async def handle_websocket(self, request: web.Request) -> web.WebSocketResponse:
            scheme = "https" if request.secure else "http"
            if not same_origin(request.headers.get("Origin"), scheme, request.host):
                log.warning(
                    "console WebSocket from another site refused: Origin %s", request.headers.get("Origin")
                )
                raise web.HTTPForbidden(text="cross-origin WebSocket refused")
            websocket = web.WebSocketResponse(heartbeat=15)
            width = to_int(request.query.get("width", "80"), 80)
            height = to_int(request.query.get("height", "24"), 24)
            tab_name = f"{name}-web{next(tabs)}"
            app_service: AppService | None = None

            async def close_websocket() -> None:  # AppService awaits it and wants no result
                await websocket.close()

            try:
                await websocket.prepare(request)
                app_service = AppService(
                    console_command(config, tab_name),
                    write_bytes=websocket.send_bytes,
                    write_str=websocket.send_str,
                    close=close_websocket,
                    download_manager=self.download_manager,
                    debug=False,
                )
                log.info("console %s opened from %s", tab_name, request.remote)
                await app_service.start(width, height)
                async for message in websocket:
                    if message.type != WSMsgType.TEXT:
                        continue
                    envelope = message.json()
                    if not isinstance(envelope, list) or not envelope:
                        continue
                    kind = envelope[0]
                    if kind == "stdin":
                        await app_service.send_bytes(str(envelope[1]).encode("utf-8"))
                    elif kind == "resize":
                        await app_service.set_terminal_size(envelope[1]["width"], envelope[1]["height"])
                    elif kind == "ping":
                        await websocket.send_json(["pong", envelope[1]])
                    elif kind == "blur":
                        await app_service.blur()
                    elif kind == "focus":
                        await app_service.focus()
            except asyncio.CancelledError:
                await websocket.close()
            except Exception:  # a browser's garbage must not take the server down
                log.exception("console %s: WebSocket error", tab_name)
            finally:
                if app_service is not None:
                    await app_service.stop()
                log.info("console %s closed", tab_name)
            return websocket

        async def on_startup(self, app: web.Application) -> None:
            who = "operator API key required" if access is not None else "NO sign-in"
            print(
                f"antalate tui --web: serving the console on http://{self.host}:{self.port}/ ({who})",
                flush=True,
            )

    return ConsoleServer(
        command=console_command(config, name),
        host=host,
        port=port,
        title="antalate operator console",
        statics_path=statics,
        templates_path=TEMPLATES,
    )


def serve(
    config: str | None, *, name: str | None, host: str, port: int, keys_file: str | None, no_auth: bool
) -> int:
    """Serve until SIGINT/SIGTERM. Refuses an open console on the network before it listens."""
    try:
        import textual_serve  # noqa: F401
    except ImportError:
        raise AntalateError("the web console needs textual-serve: pip install textual-serve") from None
    if config is not None:
        from antalate_lcm.config import load_config

        # a bad config is one clear line now, not a broken page later
        name = name or load_config(config).agent.name
    access = ConsoleAccess(load_keys(keys_file)) if keys_file else None
    if access is None and not is_loopback(host) and not no_auth:
        raise AntalateError(
            f"refusing to serve the console on {host} without sign-in: anyone who reaches it commands the "
            "swarm. Give --keys STATION_TOML (operator API keys), bind --host 127.0.0.1, or pass --no-auth"
        )
    if access is None and not is_loopback(host):
        log.warning(
            "the console on %s:%d has NO sign-in: anyone who reaches it commands the swarm", host, port
        )
    server = make_server(config, name=name or "operator", host=host, port=port, access=access)
    try:
        server.serve()
    except OSError as exc:
        raise AntalateError(f"cannot serve the console on {host}:{port}: {exc.strerror or exc}") from None
    return 0


# ------------------------------------------------------------------------------------------ CLI
def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``--web`` and its options to the ``tui`` subcommand that ``antalate_lcm.runtime`` defines."""
    p = sub.choices["tui"]
    p.add_argument("--web", action="store_true", help="serve the console to a browser (textual-serve)")
    p.add_argument(
        "--host", default=DEFAULT_HOST, help=f"--web: address to listen on (default {DEFAULT_HOST})"
    )
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"--web: port (default {DEFAULT_PORT})")
    p.add_argument(
        "--keys", metavar="STATION_TOML", help="--web: sign in with the operator API keys of this file"
    )
    p.add_argument("--no-auth", action="store_true", help="--web: allow no sign-in beyond loopback (unsafe)")
    terminal = p.get_default("func")

    def run(args: argparse.Namespace) -> int:
        if not args.web:
            return int(terminal(args))
        return serve(
            args.config,
            name=args.name,
            host=args.host,
            port=args.port,
            keys_file=args.keys,
            no_auth=args.no_auth,
        )

    p.set_defaults(func=run)
