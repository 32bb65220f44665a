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
* **Host and Origin checks** (issue 29), so another web site open in the operator's browser can
  drive the console neither through the cookie nor by DNS rebinding: a page at ``evil.example``
  whose name is re-pointed at 127.0.0.1 reaches this server *same-origin* as far as the browser
  knows, so comparing Origin with the request's own Host proves nothing. Every request's Host must
  be an address the server listens on or a name of :func:`allowed_hosts` (loopback names for a
  loopback server, ``--allow-host`` for the rest); a WebSocket's or a sign-in's Origin must be that
  same host. Anything else is 403, with or without sign-in.
* **Sign-in that cannot be guessed at speed or outlive its key**: attempts are limited per address
  (429 with ``Retry-After``), the keys file is re-read when it changes (a removed key's sessions and
  open consoles end within :data:`KEYS_POLL_S`), and sign-ins are logged once per address and outcome
  per :data:`LOG_PERIOD_S` with a count of the rest.
* **One name per tab** (``operator-web1``, ``operator-web2``, ...): two consoles under one name would
  trip the agents' per-sender replay guard (docs/security.md).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import shlex
import sys
import time
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.base.ratelimit import RateLimitedLog, TokenBucket
from operator_tui.web_access import (
    LOOPBACK_NAMES,
    SESSION_TTL_S,
    ConsoleAccess,
    KeysFile,
    Refusal,
    allowed_hosts,
    host_allowed,
    is_loopback,
    load_keys,
    same_origin,
)

if TYPE_CHECKING:
    from aiohttp import web


log = logging.getLogger("antalate.tui.web")

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
SESSION_COOKIE = "antalate_console"
TEMPLATES = Path(__file__).resolve().parent / "web_templates"
#: Sign-in attempts per address: this many at once, then one per :data:`SIGN_IN_EVERY_S`.
SIGN_IN_BURST = 5
SIGN_IN_EVERY_S = 6.0
#: How often the keys file is looked at (s): a removed key's sessions end within this.
KEYS_POLL_S = 1.0
#: Sign-ins are logged once per address and outcome per this period (s), with a count of the rest.
LOG_PERIOD_S = 60.0
#: How long a console has to quit when its browser leaves or the server stops before it is killed.
CONSOLE_QUIT_S = 5.0


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
@dataclass(eq=False)
class BrowserTab:
    """One browser tab's console, which only its own WebSocket handler closes; others ask it to.

    aiohttp's ``close()`` called from another task while the handler waits in ``receive()`` drops the
    TCP connection right after its Close frame, without waiting for the browser's Close in reply; a
    browser that sees the connection end before it has answered (its reader behind the console's
    output, on a loaded machine) reports 1006 instead of the code sent (a removed key's 4401). Closed
    by the handler, which is not reading then, the closing handshake completes before the connection
    ends."""

    #: the task relaying the browser's messages to the console, cancelled to wake the handler
    relay: asyncio.Task[None] | None = None
    #: why the console must end (WebSocket close code, message), once asked
    ending: tuple[int, bytes] | None = None

    def end(self, code: int, message: bytes) -> None:
        """Ask the handler to close the WebSocket with ``code`` (the first reason asked wins)."""
        if self.ending is None:
            self.ending = (code, message)
        if self.relay is not None:
            self.relay.cancel()


def make_server(
    config: str | None,
    *,
    name: str,
    host: str,
    port: int,
    access: ConsoleAccess | None,
    allow_hosts: Iterable[str] = (),
    keys_file: KeysFile | None = None,
    clock: Callable[[], float] = time.time,
) -> Any:
    """The textual-serve server with antalate's page, credential and per-tab names; ``keys_file``
    (where ``access``'s keys came from) is watched for changes."""
    import aiohttp_jinja2
    import jinja2
    import textual_serve
    from aiohttp import WSCloseCode, WSMsgType, web
    from textual_serve.app_service import AppService
    from textual_serve.server import Server, to_int

    statics = Path(textual_serve.__file__).resolve().parent / "static"
    KEYS_WATCHER = web.AppKey("keys_watcher", asyncio.Task[None])
    tabs = itertools.count(1)
    names = allowed_hosts(host, allow_hosts)
    attempts = TokenBucket(1.0 / SIGN_IN_EVERY_S, SIGN_IN_BURST)
    sign_ins = RateLimitedLog(log, period=LOG_PERIOD_S, clock=clock)
    refusals = RateLimitedLog(log, period=LOG_PERIOD_S, clock=clock)
    #: session token -> the consoles it opened, ended when its key is removed
    consoles: dict[str, set[BrowserTab]] = {}
    #: every console process not yet reaped (a server shutting down ends them: on_cleanup)
    running: set[AppService] = set()

    async def end_console(app_service: AppService) -> None:
        """Quit a console and reap its process while the loop runs. textual-serve's ``stop`` does
        not wait for the process; one reaped after the loop closed is an error in asyncio's waitpid
        thread, and a server stopping with consoles open (or a handler cancelled mid-stop) left
        them running."""
        try:
            await app_service.stop()
        finally:
            process = app_service._process  # textual-serve keeps its process private
            if process is not None and process.returncode is None:
                try:
                    await asyncio.wait_for(process.wait(), CONSOLE_QUIT_S)
                except asyncio.TimeoutError:
                    process.kill()
                    await process.wait()
            running.discard(app_service)

    async def relay(websocket: web.WebSocketResponse, app_service: AppService) -> None:
        """The browser's keystrokes, resizes and focus changes to its console, until the browser leaves."""
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
            app.on_cleanup.append(self.on_cleanup)
            return app

        @web.middleware
        async def _guard(
            self, request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
        ) -> web.StreamResponse:
            if not host_allowed(request.headers.get("Host"), host, names):
                refusals.log(
                    (request.remote, "host"),
                    logging.WARNING,
                    "console request from %s for another host refused (DNS rebinding?): Host %r",
                    request.remote,
                    request.headers.get("Host", "")[:100],
                )
                raise web.HTTPForbidden(text="unknown Host: this console answers only to its own address")
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
            scheme = "https" if request.secure else "http"
            if not same_origin(request.headers.get("Origin"), scheme, request.host):
                raise web.HTTPForbidden(text="cross-origin sign-in refused")
            now = clock()
            wait = attempts.take(request.remote, now)
            attempts.sweep(now)
            if wait > 0:
                refusals.log(
                    (request.remote, "throttled"),
                    logging.WARNING,
                    "console sign-in attempts from %s throttled",
                    request.remote,
                )
                raise web.HTTPTooManyRequests(
                    text=f"too many sign-in attempts: try again in {wait:.0f} s",
                    headers={"Retry-After": str(max(1, int(wait + 0.999)))},
                )
            form = await request.post()
            result = access.login(str(form.get("key", "")), now)
            if isinstance(result, Refusal):
                sign_ins.log(
                    (request.remote, "refused"),
                    logging.WARNING,
                    "console sign-in refused from %s: %s",
                    request.remote,
                    result.text,
                )
                response = aiohttp_jinja2.render_template("login.html", request, {"problem": result.text})
                response.set_status(result.status)
                return response
            token, holder = result
            sign_ins.log(
                (request.remote, "signed in"),
                logging.INFO,
                "console signed in from %s with the key of %r",
                request.remote,
                holder,
            )
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
            tab = BrowserTab()

            async def close_websocket() -> None:  # the console exited; AppService wants no result
                tab.end(WSCloseCode.OK, b"")

            token = request.cookies.get(SESSION_COOKIE, "")
            try:
                await websocket.prepare(request)
                if access is not None:
                    consoles.setdefault(token, set()).add(tab)
                app_service = AppService(
                    console_command(config, tab_name),
                    write_bytes=websocket.send_bytes,
                    write_str=websocket.send_str,
                    close=close_websocket,
                    download_manager=self.download_manager,
                    debug=False,
                )
                running.add(app_service)
                log.info("console %s opened from %s", tab_name, request.remote)
                await app_service.start(width, height)
                if tab.ending is None:
                    tab.relay = asyncio.create_task(relay(websocket, app_service))
                    try:
                        await asyncio.wait([tab.relay])  # ends when the browser leaves or tab.end()
                    finally:
                        tab.relay.cancel()
                        await asyncio.wait([tab.relay])
                    if not tab.relay.cancelled():
                        tab.relay.result()  # a browser's garbage: logged below
                if tab.ending is not None:
                    code, reason = tab.ending
                    await websocket.close(code=code, message=reason)
            except asyncio.CancelledError:
                await websocket.close()
            except Exception:  # a browser's garbage must not take the server down
                log.exception("console %s: WebSocket error", tab_name)
            finally:
                mine = consoles.get(token)
                if mine is not None:
                    mine.discard(tab)
                    if not mine:
                        del consoles[token]
                if app_service is not None:
                    # shielded: a server closing cancels this handler, and on_cleanup then reaps it too
                    await asyncio.shield(end_console(app_service))
                log.info("console %s closed", tab_name)
            return websocket

        async def _watch_keys(self) -> None:
            """Re-read the keys file when it changes; end the sessions, and close the consoles, of
            every key it no longer holds."""
            assert access is not None and keys_file is not None
            while True:
                await asyncio.sleep(KEYS_POLL_S)
                keys = keys_file.changed()
                if keys is None:
                    continue
                ended = access.replace_keys(keys)
                log.warning(
                    "console keys file %s re-read: %d operator key(s); %d session(s) of removed keys ended",
                    keys_file.path,
                    sum(k.role == "operator" for k in keys),
                    len(ended),
                )
                for token in ended:
                    for tab in consoles.pop(token, ()):
                        tab.end(4401, b"your key was removed")

        async def on_startup(self, app: web.Application) -> None:
            if access is not None and keys_file is not None:
                app[KEYS_WATCHER] = asyncio.get_running_loop().create_task(self._watch_keys())
            who = "operator API key required" if access is not None else "NO sign-in"
            print(
                f"antalate tui --web: serving the console on http://{self.host}:{self.port}/ ({who})",
                flush=True,
            )

        async def on_cleanup(self, app: web.Application) -> None:
            watcher = app.get(KEYS_WATCHER)
            if watcher is not None:
                watcher.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await watcher
            await asyncio.gather(*(end_console(s) for s in list(running)), return_exceptions=True)

    return ConsoleServer(
        command=console_command(config, name),
        host=host,
        port=port,
        title="antalate operator console",
        statics_path=statics,
        templates_path=TEMPLATES,
    )


def serve(
    config: str | None,
    *,
    name: str | None,
    host: str,
    port: int,
    keys_file: str | None,
    no_auth: bool,
    allow_hosts: tuple[str, ...] = (),
) -> int:
    """Serve until SIGINT/SIGTERM. Refuses an open console on the network before it listens."""
    try:
        import textual_serve  # noqa: F401
    except ImportError:
        raise AntalateError("the web console needs textual-serve: pip install textual-serve") from None
    if config is not None:
        from antalate_lcm.core.config import load_config

        # a bad config is one clear line now, not a broken page later
        name = name or load_config(config).agent.name
    keys = KeysFile(keys_file) if keys_file else None
    access = ConsoleAccess(keys.load()) if keys is not None else None
    if access is None and allow_hosts and not no_auth:
        raise AntalateError(
            "refusing --allow-host on a console without sign-in: a loopback console without keys answers "
            "only to 127.0.0.1, localhost and [::1]. Give --keys STATION_TOML, or pass --no-auth"
        )
    if access is None and not is_loopback(host) and not no_auth:
        raise AntalateError(
            f"refusing to serve the console on {host} without sign-in: anyone who reaches it commands the "
            "swarm. Give --keys STATION_TOML (operator API keys), bind --host 127.0.0.1, or pass --no-auth"
        )
    if access is None and not is_loopback(host):
        log.warning(
            "the console on %s:%d has NO sign-in: anyone who reaches it commands the swarm", host, port
        )
    server = make_server(
        config,
        name=name or "operator",
        host=host,
        port=port,
        access=access,
        allow_hosts=allow_hosts,
        keys_file=keys,
    )
    try:
        server.serve()
    except OSError as exc:
        raise AntalateError(f"cannot serve the console on {host}:{port}: {exc.strerror or exc}") from None
    return 0


__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "KEYS_POLL_S",
    "LOG_PERIOD_S",
    "LOOPBACK_NAMES",
    "SESSION_COOKIE",
    "SESSION_TTL_S",
    "SIGN_IN_BURST",
    "SIGN_IN_EVERY_S",
    "ConsoleAccess",
    "BrowserTab",
    "KeysFile",
    "Refusal",
    "allowed_hosts",
    "console_command",
    "host_allowed",
    "is_loopback",
    "load_keys",
    "make_server",
    "same_origin",
    "serve",
]


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
