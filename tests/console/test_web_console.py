"""``antalate tui --web``: the console in a browser.

The server's own rules run in-process against the real aiohttp app (sign-in, cookies, origin check,
a page that loads nothing from outside). The whole path runs in a private namespace: a swarm of
two simulated agents, the web console, and Debian's headless Chromium driven through its DevTools
protocol (tests/console/cdp_console.py): the page shows both agents, ``T`` + ``y`` takes them off, a
screenshot is written, and the page requested nothing outside 127.0.0.1.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from aiohttp.test_utils import TestClient, TestServer
from aiohttp.web import Application, Request

from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.station._auth import new_api_key, sha256_hex
from antalate_lcm.station._settings import ApiKey
from operator_tui import web
from tests import REPO
from tests.conftest import MCAST_URL, Probe
from tests.harness.agents import agent_config
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.process import stop_process

OPERATOR_KEY, READER_KEY = new_api_key(), new_api_key()
KEYS = (
    ApiKey(name="alice", role="operator", sha256=sha256_hex(OPERATOR_KEY)),
    ApiKey(name="bob", role="read-only", sha256=sha256_hex(READER_KEY)),
)


def keys_toml() -> str:
    return "".join(
        f'[[api_keys]]\nname = "{k.name}"\nrole = "{k.role}"\nsha256 = "{k.sha256}"\n' for k in KEYS
    )


# -- sign-in logic (pure) --------------------------------------------------------------------------


def session(access: web.ConsoleAccess, key: str, now: float) -> tuple[str, str]:
    """A session the key must open: (token, holder)."""
    opened = access.login(key, now=now)
    assert not isinstance(opened, web.Refusal), opened
    return opened


def test_only_an_operator_key_opens_a_session_and_sessions_expire() -> None:
    access = web.ConsoleAccess(KEYS, ttl_s=100.0)
    assert access.login("antk_not-a-key", now=0.0) == web.Refusal(401, "Unknown API key.")
    refused = access.login(READER_KEY, now=0.0)
    assert (
        isinstance(refused, web.Refusal) and refused.status == 403 and "needs an operator key" in refused.text
    )
    token, holder = session(access, f"  {OPERATOR_KEY}\n", now=0.0)  # pasted with blanks
    assert holder == "alice"
    assert access.holder(token, now=50.0) == "alice"
    assert access.holder("forged-token", now=50.0) is None and access.holder(None, now=50.0) is None
    assert access.holder(token, now=101.0) is None
    assert token not in access.sessions


@pytest.mark.parametrize(
    ("host", "loopback"),
    [("127.0.0.1", True), ("localhost", True), ("::1", True), ("0.0.0.0", False), ("10.0.0.5", False)],
)
def test_loopback_hosts(host: str, loopback: bool) -> None:
    assert web.is_loopback(host) is loopback


@pytest.mark.parametrize(
    ("listen", "extra", "host", "allowed"),
    [
        ("127.0.0.1", (), "127.0.0.1:8000", True),
        ("127.0.0.1", (), "localhost:8000", True),
        ("127.0.0.1", (), "LOCALHOST", True),
        ("127.0.0.1", (), "[::1]:8000", True),
        ("127.0.0.1", (), "127.0.0.2:8000", True),  # loopback all the same
        ("127.0.0.1", (), "10.0.0.5:8000", False),  # an address this server does not listen on
        ("127.0.0.1", (), "evil.example:8000", False),  # DNS rebinding
        ("127.0.0.1", (), "localhost.evil.example", False),
        ("127.0.0.1", (), "", False),
        ("127.0.0.1", ("console.lan",), "console.lan:8000", True),
        ("10.0.0.5", (), "10.0.0.5:8000", True),
        ("10.0.0.5", (), "localhost:8000", False),  # not on loopback: localhost is another machine's name
        ("10.0.0.5", (), "10.0.0.6", False),
        ("0.0.0.0", (), "192.0.2.7:8000", True),  # any address of ours; an IP literal cannot be rebound
        ("0.0.0.0", (), "evil.example", False),
        ("::", ("field.example",), "[2001:db8::1]:8000", True),
        ("::", ("field.example",), "FIELD.example:8000", True),
    ],
)
def test_which_hosts_a_console_answers_to(
    listen: str, extra: tuple[str, ...], host: str, allowed: bool
) -> None:
    assert web.host_allowed(host, listen, web.allowed_hosts(listen, extra)) is allowed


def test_replacing_the_keys_ends_the_sessions_of_removed_or_demoted_keys() -> None:
    carol = new_api_key()
    access = web.ConsoleAccess((*KEYS, ApiKey(name="carol", role="operator", sha256=sha256_hex(carol))))
    alice_token, _ = session(access, OPERATOR_KEY, now=0.0)
    carol_token, _ = session(access, carol, now=0.0)
    demoted = ApiKey(name="carol", role="read-only", sha256=sha256_hex(carol))
    assert access.replace_keys((*KEYS, demoted)) == [carol_token]
    assert access.holder(carol_token, now=1.0) is None and access.holder(alice_token, now=1.0) == "alice"
    assert isinstance(access.login(carol, now=1.0), web.Refusal)
    assert access.replace_keys(()) == [alice_token]  # an unusable keys file: nobody stays signed in


# -- the real aiohttp app, in-process --------------------------------------------------------------


async def client_for(access: web.ConsoleAccess | None) -> TestClient[Request, Application]:
    server = web.make_server(None, name="operator", host="127.0.0.1", port=0, access=access)
    client = TestClient(TestServer(await server._make_app(), host="127.0.0.1"))
    await client.start_server()
    return client


async def test_the_page_loads_nothing_from_outside_and_its_assets_are_served() -> None:
    client = await client_for(None)
    try:
        page = await client.get("/")
        assert page.status == 200
        html = await page.text()
        refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)["']|url\(["']?([^"')]+)""", html)
        urls = [a or b for a, b in refs]
        assert urls, html
        outside = [u for u in urls if re.match(r"^[a-z]+:", u)]
        assert outside == [], f"the page refers outside itself: {outside}"
        assert "googleapis" not in html
        ws = re.search(r'data-session-websocket-url="([^"]+)"', html)
        assert ws and ws[1] == f"ws://{client.server.host}:{client.server.port}/ws"
        for url in urls:
            asset = await client.get("/" + url)
            assert asset.status == 200, url
        assert (await client.get("/static/")).status in (403, 404)  # no directory listing
    finally:
        await client.close()


async def test_sign_in_cookie_and_websocket_guard() -> None:
    client = await client_for(web.ConsoleAccess(KEYS))
    try:
        first = await client.get("/", allow_redirects=False)
        assert first.status == 303 and first.headers["Location"] == "login"
        assert (await client.get("/ws")).status == 401
        wrong = await client.post("/login", data={"key": "antk_guess"}, allow_redirects=False)
        assert wrong.status == 401 and "Unknown API key." in await wrong.text()
        reader = await client.post("/login", data={"key": READER_KEY}, allow_redirects=False)
        assert reader.status == 403 and "needs an operator key" in await reader.text()
        assert web.SESSION_COOKIE not in client.session.cookie_jar.filter_cookies(client.make_url("/"))
        ok = await client.post("/login", data={"key": OPERATOR_KEY}, allow_redirects=False)
        assert ok.status == 303 and ok.headers["Location"] == "/"
        cookie = ok.headers["Set-Cookie"]
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
        assert (await client.get("/")).status == 200
        # signed in, but a page of another site opening the WebSocket with the cookie is refused
        evil = await client.get(
            "/ws",
            headers={
                "Origin": "http://evil.example",
                "Connection": "Upgrade",
                "Upgrade": "websocket",
                "Sec-WebSocket-Version": "13",
                "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
            },
        )
        assert evil.status == 403
    finally:
        await client.close()


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "tui", "--web", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )


def test_an_open_console_on_the_network_is_refused_before_it_listens(tmp_path: Path) -> None:
    proc = run_cli("--host", "0.0.0.0", "--port", "1")
    assert proc.returncode == 2
    assert (
        "refusing to serve the console on 0.0.0.0 without sign-in" in proc.stderr and "--keys" in proc.stderr
    )
    readers = tmp_path / "readers.toml"
    readers.write_text(f'[[api_keys]]\nname = "bob"\nrole = "read-only"\nsha256 = "{KEYS[1].sha256}"\n')
    proc = run_cli("--keys", str(readers), "--port", "1")
    assert proc.returncode == 2 and 'no [[api_keys]] entry with role = "operator"' in proc.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text('[[api_keys]]\nname = "x"\nrole = "operator"\nsha256 = "abc"\n')
    proc = run_cli("--keys", str(bad), "--port", "1")
    assert proc.returncode == 2 and "api_keys" in proc.stderr and "Traceback" not in proc.stderr


# -- in a browser ----------------------------------------------------------------------------------


def chromium() -> str | None:
    override = os.environ.get("ANTALATE_TEST_CHROMIUM")
    if override:
        return override
    return next((p for p in map(shutil.which, ("chromium", "chromium-browser")) if p), None)


def screenshot_dir(tmp_path: Path) -> Path:
    """Where the screenshot goes: $ANTALATE_SCREENSHOTS if set (CI artefacts), else the test's tmp."""
    target = Path(os.environ.get("ANTALATE_SCREENSHOTS") or tmp_path)
    target.mkdir(parents=True, exist_ok=True)
    return target


def _drain(stream: Any) -> None:
    try:
        for _ in stream:
            pass
    except (ValueError, OSError):  # closed when the browser is stopped
        pass


def read_devtools_url(proc: subprocess.Popen[str], deadline_s: float) -> str | None:
    assert proc.stderr is not None
    deadline = time.monotonic() + deadline_s
    seen = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        m = re.search(r"DevTools listening on (ws://[^\s]+)", line)
        if m:
            # keep reading its log, or a chatty Chromium blocks on a full pipe
            threading.Thread(target=_drain, args=(proc.stderr,), daemon=True).start()
            return m[1]
    raise AssertionError("Chromium did not start:\n" + "".join(seen[-30:]))


@pytest.mark.netns
def test_web_console_in_chromium_shows_the_swarm_and_takes_it_off(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    browser = chromium()
    if browser is None:
        pytest.skip("chromium not found (Debian: apt-get install chromium; or set ANTALATE_TEST_CHROMIUM)")
    agents_cfg = tmp_path / "swarm.toml"
    agents_cfg.write_text(tomli_w.dumps(agent_config("alpha", security={"insecure": True})))
    operator_cfg = tmp_path / "operator.toml"
    operator_cfg.write_text(
        f'[agent]\nname = "operator"\n[buses]\nlan = "{MCAST_URL}"\n[topics]\ndefault_bus = "lan"\n'
    )
    keys = tmp_path / "keys.toml"
    keys.write_text(keys_toml())
    key_file = tmp_path / "operator.key"
    key_file.write_text(OPERATOR_KEY + "\n")
    port = 8765
    shot = screenshot_dir(tmp_path) / "web-console.png"
    logs = {n: open(tmp_path / f"{n}.log", "w") for n in ("swarm", "web")}  # noqa: SIM115 - closed below
    swarm = netns.antalate(
        "agent", str(agents_cfg), "--agents", "2", stdout=logs["swarm"], stderr=subprocess.STDOUT
    )
    server = netns.antalate(
        "tui",
        "--web",
        str(operator_cfg),
        "--port",
        str(port),
        "--keys",
        str(keys),
        stdout=logs["web"],
        stderr=subprocess.STDOUT,
    )
    chrome = netns.popen(
        [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--no-default-browser-check",
            "--remote-debugging-port=0",
            f"--user-data-dir={tmp_path / 'chrome'}",
            "--window-size=1280,860",
            "about:blank",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        assert probe.wait("alpha-02/MC_STATE", "mc_state_t", timeout=30, state=M.STANDBY)
        assert wait_for(lambda: "serving the console" in (tmp_path / "web.log").read_text(), 30), (
            tmp_path / "web.log"
        ).read_text()
        devtools = read_devtools_url(chrome, 60)
        assert devtools is not None
        http = "http://" + devtools.split("/")[2]
        drive = netns.run(
            [
                sys.executable,
                "-m",
                "tests.console.cdp_console",
                http,
                f"http://127.0.0.1:{port}/",
                str(key_file),
                str(shot),
                "alpha-01",
                "alpha-02",
            ],
            timeout=240,
            env=dict(os.environ, PYTHONPATH=str(REPO)),
            cwd=str(REPO),
        )
        lines = [line for line in drive.stdout.splitlines() if line.startswith("{")]
        assert lines, f"driver said nothing:\n{drive.stdout}\n{drive.stderr}"
        seen = json.loads(lines[-1])
        assert "error" not in seen, (
            f"{seen.get('error')}\nJS errors: {seen['js_errors']}\nweb log:\n{(tmp_path / 'web.log').read_text()[-3000:]}"
        )
        assert seen["agents_shown"] == ["alpha-01", "alpha-02"]
        for agent in ("alpha-01", "alpha-02"):
            assert probe.wait(f"{agent}/MC_STATE", "mc_state_t", timeout=30, state=M.MISSION), (
                f"{agent} did not take off"
            )
        outside = [
            u
            for u in seen["requests"]
            if not re.match(rf"^(https?|wss?)://127\.0\.0\.1:{port}/", u)
            and not u.startswith(("data:", "about:"))
        ]
        assert outside == [], f"the page requested outside 127.0.0.1: {outside}"
        assert any(u.startswith(f"ws://127.0.0.1:{port}/ws") for u in seen["requests"])
        assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 10_000
        print(f"screenshot: {shot}")
        web_log = (tmp_path / "web.log").read_text()
        assert "signed in from 127.0.0.1 with the key of 'alice'" in web_log
        assert "console operator-web1 opened" in web_log
    finally:
        for proc in (chrome, server, swarm):
            stop_process(proc)
        for f in logs.values():
            f.close()
