"""Issue 29, findings 5 and 6: the web console (``antalate tui --web``) against a web page and a guesser.

The attacks run against the real aiohttp app of :func:`operator_tui.web.make_server`, served on a
loopback port in this process, and against a real ``antalate tui --web`` process (its log is
judged). The consoles a WebSocket opens speak to a ``memq://`` bus: nothing leaves the process.

What is judged is what the server answered and did (status, headers, open sessions, its log), never
what the attacker thinks happened.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from aiohttp.test_utils import TestServer

from antalate_lcm.station._auth import new_api_key, sha256_hex
from antalate_lcm.station._settings import ApiKey
from operator_tui import web
from tests import REPO
from tests.harness.polling import wait_for
from tests.harness.process import stop_process

ALICE, CAROL, READER = new_api_key(), new_api_key(), new_api_key()
EVIL = "rebind.evil.example"
UPGRADE = {
    "Connection": "Upgrade",
    "Upgrade": "websocket",
    "Sec-WebSocket-Version": "13",
    "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
}


def keys_toml(*keys: tuple[str, str, str]) -> str:
    return "".join(
        f'[[api_keys]]\nname = "{name}"\nrole = "{role}"\nsha256 = "{sha256_hex(key)}"\n'
        for name, role, key in keys
    )


def load_keys(tmp: Path, text: str) -> tuple[ApiKey, ...]:
    path = tmp / "keys.toml"
    path.write_text(text)
    return web.load_keys(str(path))


def operator_config(tmp: Path) -> Path:
    """A console config on an in-process bus: a console the test opens reaches no network."""
    path = tmp / "operator.toml"
    path.write_text('[agent]\nname = "operator"\n[buses]\nlan = "memq://"\n[topics]\ndefault_bus = "lan"\n')
    return path


class Console:
    """A served console app and raw requests to it with any Host, Origin and source address."""

    def __init__(self, server: TestServer) -> None:
        self.server = server
        self.port = server.port
        self.url = f"http://127.0.0.1:{server.port}"

    async def request(
        self,
        method: str,
        path: str,
        *,
        host: str | None = None,
        source: str = "127.0.0.1",
        **kwargs: object,
    ) -> aiohttp.ClientResponse:
        headers = dict(kwargs.pop("headers", {}) or {})  # type: ignore[call-overload]
        headers["Host"] = host if host is not None else f"127.0.0.1:{self.port}"
        connector = aiohttp.TCPConnector(local_addr=(source, 0), force_close=True)
        async with aiohttp.ClientSession(connector=connector) as session:
            response = await session.request(
                method,
                self.url + path,
                headers=headers,
                allow_redirects=False,
                **kwargs,
            )
            await response.read()
            return response


async def serve(
    access: web.ConsoleAccess | None,
    *,
    config: Path | None = None,
    allow_hosts: tuple[str, ...] = (),
    keys_file: web.KeysFile | None = None,
) -> Console:
    extra: dict[str, Any] = {}
    if allow_hosts:
        extra["allow_hosts"] = allow_hosts
    if keys_file is not None:
        extra["keys_file"] = keys_file
    server = web.make_server(
        str(config) if config else None, name="operator", host="127.0.0.1", port=0, access=access, **extra
    )
    test_server = TestServer(await server._make_app(), host="127.0.0.1")
    await test_server.start_server()
    return Console(test_server)


@pytest.fixture
async def open_console(tmp_path: Path) -> AsyncIterator[Console]:
    """The default console: loopback, no sign-in (the one the rebinding attack drove)."""
    console = await serve(None, config=operator_config(tmp_path))
    yield console
    await console.server.close()


# ------------------------------------------------------------------ finding 5: DNS rebinding
@pytest.mark.attack("DNS rebinding drives the loopback console without sign-in (issue 29.5)")
async def test_dns_rebinding_against_the_console_without_sign_in_gets_403(open_console: Console) -> None:
    c = open_console
    # the legitimate operator's names for it answer
    for host in (f"127.0.0.1:{c.port}", f"localhost:{c.port}", "127.0.0.1", f"LocalHost:{c.port}"):
        assert (await c.request("GET", "/", host=host)).status == 200, host
    # a page of evil.example whose name now resolves to 127.0.0.1: Host and Origin are both the attacker's
    evil_host = f"{EVIL}:{c.port}"
    origin = {"Origin": f"http://{evil_host}"}
    ws = await c.request("GET", "/ws", host=evil_host, headers={**origin, **UPGRADE})
    assert ws.status == 403, f"the rebinding WebSocket got {ws.status}"
    page = await c.request("GET", "/", host=evil_host, headers=origin)
    assert page.status == 403
    assert (await c.request("GET", "/static/textual.js", host=evil_host)).status == 403
    # names that only look like ours, an address this loopback server does not listen on, no Host
    for host in (f"localhost.{EVIL}", f"127.0.0.1.{EVIL}:{c.port}", f"10.1.2.3:{c.port}", ""):
        assert (await c.request("GET", "/", host=host)).status in (400, 403), host


@pytest.mark.attack("DNS rebinding against a keyed console on an allowed name (issue 29.5)")
async def test_allow_listed_name_answers_and_cross_site_requests_on_it_do_not(tmp_path: Path) -> None:
    access = web.ConsoleAccess(load_keys(tmp_path, keys_toml(("alice", "operator", ALICE))))
    c = await serve(access, allow_hosts=("console.field.lan",))
    try:
        host = f"console.field.lan:{c.port}"
        assert (await c.request("GET", "/login", host=host)).status == 200
        assert (await c.request("GET", "/login", host=f"{EVIL}:{c.port}")).status == 403
        # a cross-site form posting a key (login CSRF) and a cross-site WebSocket on the right Host
        evil_origin = {"Origin": f"http://{EVIL}:{c.port}"}
        csrf = await c.request("POST", "/login", host=host, headers=evil_origin, data={"key": ALICE})
        assert csrf.status == 403 and "Set-Cookie" not in csrf.headers
        ws = await c.request("GET", "/ws", host=host, headers={**evil_origin, **UPGRADE})
        assert ws.status in (401, 403)
        ok = await c.request(
            "POST", "/login", host=host, headers={"Origin": f"http://{host}"}, data={"key": ALICE}
        )
        assert ok.status == 303 and web.SESSION_COOKIE in ok.headers.get("Set-Cookie", "")
    finally:
        await c.server.close()


def test_a_keyless_console_refuses_an_allow_list() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "tui", "--web", "--port", "1", "--allow-host", EVIL],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        timeout=60,
    )
    assert proc.returncode == 2 and "refusing --allow-host on a console without sign-in" in proc.stderr


# ------------------------------------------------------------------ finding 6: sign-in
@pytest.mark.attack("guessing operator keys at speed (issue 29.6)")
async def test_sign_in_is_throttled_per_address_with_retry_after(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    access = web.ConsoleAccess(load_keys(tmp_path, keys_toml(("alice", "operator", ALICE))))
    c = await serve(access)
    caplog.set_level(logging.INFO, logger="antalate.tui.web")
    try:
        statuses = []
        throttled = None
        for i in range(60):  # the run: 300 guesses in 0.5 s
            r = await c.request("POST", "/login", data={"key": f"antk_guess{i}"}, source="127.0.0.2")
            statuses.append(r.status)
            if r.status == 429 and throttled is None:
                throttled = r
        assert statuses[: web.SIGN_IN_BURST] == [401] * web.SIGN_IN_BURST, statuses
        assert set(statuses[web.SIGN_IN_BURST :]) == {429}, statuses
        assert throttled is not None
        retry = int(throttled.headers["Retry-After"])
        assert 1 <= retry <= web.SIGN_IN_EVERY_S + 1
        # the right key from the throttled address waits too: the guesser learns nothing from it
        right = await c.request("POST", "/login", data={"key": ALICE}, source="127.0.0.2")
        assert right.status == 429 and "Set-Cookie" not in right.headers
        # another address keeps its own budget
        other = await c.request("POST", "/login", data={"key": ALICE}, source="127.0.0.3")
        assert other.status == 303
        # ~62 attempts, a handful of log lines: each address and outcome once per period
        lines = [r.getMessage() for r in caplog.records if r.name == "antalate.tui.web"]
        assert sum("sign-in refused from 127.0.0.2" in line for line in lines) == 1, lines
        assert sum("throttled" in line for line in lines) == 1, lines
        assert sum("signed in from 127.0.0.3" in line for line in lines) == 1, lines
        # after Retry-After the address may try again
        await asyncio.sleep(retry)
        again = await c.request("POST", "/login", data={"key": ALICE}, source="127.0.0.2")
        assert again.status == 303
    finally:
        await c.server.close()


async def _alice_and_carol(tmp_path: Path) -> tuple[Path, web.ConsoleAccess, Console]:
    """A console whose keys file (returned, for the test to edit) holds two operators, alice and carol."""
    keys = tmp_path / "keys.toml"
    keys.write_text(keys_toml(("alice", "operator", ALICE), ("carol", "operator", CAROL)))
    keys_file = web.KeysFile(str(keys))
    access = web.ConsoleAccess(keys_file.load())
    return keys, access, await serve(access, config=operator_config(tmp_path), keys_file=keys_file)


@pytest.mark.attack("a removed operator key keeps its session and open console (issue 29.6)")
async def test_a_removed_key_ends_its_sessions_and_consoles_within_seconds(tmp_path: Path) -> None:
    keys, access, c = await _alice_and_carol(tmp_path)
    try:
        cookies = {}
        for name, key in (("alice", ALICE), ("carol", CAROL)):
            r = await c.request("POST", "/login", data={"key": key})
            assert r.status == 303, name
            cookies[name] = r.cookies[web.SESSION_COOKIE].value
        jar = {n: {"Cookie": f"{web.SESSION_COOKIE}={v}"} for n, v in cookies.items()}
        assert (await c.request("GET", "/", headers=jar["carol"])).status == 200
        # carol opens a console (a real one: python -m operator_tui on a memq:// bus)
        async with aiohttp.ClientSession(cookies={web.SESSION_COOKIE: cookies["carol"]}) as session:
            ws = await session.ws_connect(f"ws://127.0.0.1:{c.port}/ws?width=80&height=24")
            first = await asyncio.wait_for(ws.receive(), 30)
            assert first.type in (aiohttp.WSMsgType.BINARY, aiohttp.WSMsgType.TEXT), first
            time.sleep(0.01)  # let the file's mtime move on coarse clocks
            keys.write_text(keys_toml(("alice", "operator", ALICE)))
            removed_at = time.monotonic()
            closed = None
            while time.monotonic() - removed_at < 10:
                try:
                    msg = await asyncio.wait_for(ws.receive(), 10)
                except asyncio.TimeoutError:
                    break
                if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING):
                    closed = time.monotonic() - removed_at
                    break
            assert closed is not None, "carol's console stayed open after her key was removed"
            assert closed <= web.KEYS_POLL_S * 3 + 2, closed
            assert ws.close_code == 4401
        assert (await c.request("GET", "/", headers=jar["carol"])).status == 303  # back to sign-in
        refused = await c.request("POST", "/login", data={"key": CAROL}, source="127.0.0.4")
        assert refused.status == 401
        assert (await c.request("GET", "/", headers=jar["alice"])).status == 200  # alice is untouched
        # a keys file that becomes unusable ends every session (fail closed)
        keys.write_text("[[api_keys]]\nname = 1\n")
        assert await _eventually(lambda: c.request("GET", "/", headers=jar["alice"]), 303)
    finally:
        await c.server.close()


@pytest.mark.attack("a removed operator key's console told it was removed, browser not reading (issue 29.6)")
async def test_a_browser_behind_on_reading_still_gets_the_removed_key_close_code(tmp_path: Path) -> None:
    """The browser reads the server's Close only after the server has ended the console (a loaded
    machine, a reader behind the console's output): it must still see 4401, which it can only if
    the server waits for its Close in reply before ending the connection. Ending it at once made
    the browser's reply fail, and it reported 1006."""
    keys, access, c = await _alice_and_carol(tmp_path)
    try:
        r = await c.request("POST", "/login", data={"key": CAROL})
        cookie = r.cookies[web.SESSION_COOKIE].value
        async with aiohttp.ClientSession(cookies={web.SESSION_COOKIE: cookie}) as session:
            ws = await session.ws_connect(f"ws://127.0.0.1:{c.port}/ws?width=80&height=24")
            first = await asyncio.wait_for(ws.receive(), 30)
            assert first.type in (aiohttp.WSMsgType.BINARY, aiohttp.WSMsgType.TEXT), first
            time.sleep(0.01)  # let the file's mtime move on coarse clocks
            keys.write_text(keys_toml(("alice", "operator", ALICE)))
            deadline = time.monotonic() + 10
            while access.sessions and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            assert not access.sessions, "carol's session outlived her key"
            await asyncio.sleep(1.0)  # the server closes meanwhile; this browser reads nothing yet
            while True:
                msg = await asyncio.wait_for(ws.receive(), 10)
                if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING):
                    break
            assert ws.close_code == 4401, msg
    finally:
        await c.server.close()


def _children() -> set[int]:
    """This process's child processes (Linux: /proc/PID/task/TID/children)."""
    pids: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        with contextlib.suppress(OSError):
            pids.update(int(p) for p in (task / "children").read_text().split())
    return pids


async def test_a_console_process_is_reaped_before_the_server_has_stopped(tmp_path: Path) -> None:
    """A console's process is reaped while the server's loop runs (here: its browser left, then the
    server stopped). textual-serve's stop does not wait for it: the process outlived the server, and
    asyncio's waitpid thread later failed on a closed loop ("Event loop is closed"), its traceback
    formatted beside the main thread's parsing, which broke CPython 3.11's AST state for the worker."""
    before = _children()
    c = await serve(None, config=operator_config(tmp_path))
    async with aiohttp.ClientSession() as session:
        ws = await session.ws_connect(f"ws://127.0.0.1:{c.port}/ws?width=80&height=24")
        first = await asyncio.wait_for(ws.receive(), 30)
        assert first.type in (aiohttp.WSMsgType.BINARY, aiohttp.WSMsgType.TEXT), first
        assert _children() - before, "the console runs as a child process"
        await ws.close()  # the browser leaves: its console quits
    await c.server.close()
    assert _children() - before == set()


async def _eventually(call: object, status: int, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if (await call()).status == status:  # type: ignore[operator]
            return True
        await asyncio.sleep(0.2)
    return False


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.attack("DNS rebinding against the real antalate tui --web process (issue 29.5)")
def test_the_real_process_refuses_a_rebinding_request(tmp_path: Path) -> None:
    port = _free_port()
    log_path = tmp_path / "web.log"
    with log_path.open("w") as out:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "antalate_lcm.cli",
                "tui",
                "--web",
                str(operator_config(tmp_path)),
                "--port",
                str(port),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONPATH=str(REPO)),
            text=True,
        )
        try:
            assert wait_for(lambda: "serving the console" in log_path.read_text(), 60), log_path.read_text()

            def raw(host: str) -> str:
                with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
                    head = "".join(f"{k}: {v}\r\n" for k, v in UPGRADE.items())
                    s.sendall(
                        f"GET /ws HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n{head}\r\n".encode()
                    )
                    return s.recv(200).decode("latin-1").split("\r\n", 1)[0]

            assert raw(f"{EVIL}:{port}").startswith("HTTP/1.1 403"), raw(f"{EVIL}:{port}")
            # the 403 can reach the test before the console's log line reaches the file
            assert wait_for(lambda: "(DNS rebinding?)" in log_path.read_text(), 10), log_path.read_text()
        finally:
            stop_process(proc)
