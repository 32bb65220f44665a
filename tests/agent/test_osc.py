"""The OSC against the real station, and against servers that are down, hang or answer garbage."""

from __future__ import annotations

import http.server
import json
import logging
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TypeVar

import httpx
import pytest

from antalate_lcm.agent.osc import OscNode, wire
from antalate_lcm.agent.osc.node import tls_context
from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import parse_config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context
from antalate_lcm.msgs import direction_cmd_t, mc_state_t, operator_cmd_t, payload_t, telemetry_t
from antalate_lcm.station import StationServer, StationSettings
from antalate_lcm.station._auth import registration_key, sha256_hex
from antalate_lcm.station.client import StationClient, build_operator_cmd, operator_cmd_wire
from antalate_lcm.wire.security import generate_key
from tests.conftest import Probe
from tests.harness.agents import AgentProcesses, agent_config
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.tls import make_tls
from tests.station.test_station import API_KEYS, AUTH, OPERATOR_KEY


def make_osc(
    server: str, *, security: dict[str, Any] | None = None, **osc: Any
) -> tuple[OscNode, Context, dict[str, list[Any]]]:
    cfg = parse_config(
        {
            "agent": {"name": "alpha"},
            "buses": {"lan": "memq://"},
            "osc": {
                "enabled": True,
                "server": server,
                "rate": 20.0,
                "timeout": 0.5,
                "max_backoff": 0.5,
                **osc,
            },
            "security": security or {},
        }
    )
    ctx = Context(Buses(cfg.buses), Executor())
    ctx.executor.start()
    got: dict[str, list[Any]] = {"cmd": [], "dir": [], "payload": []}
    ctx.buses.subscribe("lan", "alpha/OPERATOR_CMD", operator_cmd_t, lambda c, m: got["cmd"].append(m))
    ctx.buses.subscribe("lan", "alpha/DIRECTION_CMD", direction_cmd_t, lambda c, m: got["dir"].append(m))
    ctx.buses.subscribe("lan", "alpha/OPERATOR_PAYLOAD", payload_t, lambda c, m: got["payload"].append(m))
    node = OscNode(cfg, ctx)
    node.start()
    return node, ctx, got


def feed_state(ctx: Context, lat: float = 32.0, heading: float = 0.0) -> None:
    mc = mc_state_t()
    mc.state = mc_state_t.MISSION
    ctx.buses.publish("lan", "alpha/MC_STATE", mc)
    t = telemetry_t()
    t.header.agent = "alpha"
    t.lat, t.lon, t.heading, t.battery, t.mode = lat, 35.0, heading, 80.0, "SIM"
    ctx.buses.publish("lan", "alpha/TELEMETRY", t)


@pytest.fixture
def station(tmp_path: Path) -> Iterator[StationServer]:
    settings = StationSettings(
        db_path=str(tmp_path / "station.sqlite"), range_m=100, fov_deg=60, api_keys=API_KEYS
    )
    with StationServer(settings) as srv:
        yield srv


def test_reports_get_a_token_and_deliver_commands_once(station: StationServer) -> None:
    node, ctx, got = make_osc(station.url)
    try:
        feed_state(ctx)
        assert wait_for(lambda: node.token, 5)

        def listed() -> list[dict[str, Any]]:
            return list(httpx.get(f"{station.url}/api/agents", headers=AUTH).json())

        assert wait_for(lambda: any(a.get("mc_state") == "MISSION" for a in listed()), 5), listed()
        r = httpx.post(
            f"{station.url}/api/commands", json={"command": "RTL", "target": "alpha"}, headers=AUTH
        )
        assert r.status_code == 200, r.text
        seq = r.json()["seq"]
        assert wait_for(lambda: got["cmd"], 5)
        cmd = got["cmd"][0]
        assert cmd.command == operator_cmd_t.RTL and cmd.header.seq == seq and cmd.target == "alpha"
        httpx.post(
            f"{station.url}/api/commands", json={"direction": {"azimuth": 90, "speed": 1.5}}, headers=AUTH
        )
        assert wait_for(lambda: got["dir"], 5)
        d = got["dir"][0]
        assert d.active and d.azimuth == 90 and d.speed == 1.5
        # the station's payload (peer detection JSON) reaches the bus
        assert wait_for(lambda: got["payload"], 5)
        p = got["payload"][-1]
        assert p.content_type == "application/json" and "detected" in json.loads(bytes(p.data))
        time.sleep(0.5)
        assert len(got["cmd"]) == 1, "a command is delivered once"
    finally:
        node.stop()
        ctx.close()


def test_token_is_kept_across_reports(station: StationServer) -> None:
    node, ctx, _ = make_osc(station.url)
    try:
        feed_state(ctx)
        first = wait_for(lambda: node.token, 5)
        assert wait_for(lambda: node.reports_ok > 5, 5)
        assert node.token == first
        assert len(httpx.get(f"{station.url}/api/agents", headers=AUTH).json()) == 1
    finally:
        node.stop()
        ctx.close()


# ----------------------------------------------------------------------------- misbehaving servers


S = TypeVar("S", bound=http.server.ThreadingHTTPServer)


class _FakeStation(http.server.BaseHTTPRequestHandler):
    """A station of the test's making: every POST is answered with what ``reply`` says."""

    def log_message(self, *args: Any) -> None:
        pass

    def reply(self) -> tuple[bytes, int]:
        raise NotImplementedError

    def do_POST(self) -> None:  # noqa: N802 - http.server's API
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        body, status = self.reply()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


class _Garbage(_FakeStation):
    def reply(self) -> tuple[bytes, int]:
        assert isinstance(self.server, GarbageServer)
        return {
            "bad_json": (b"{not json", 200),
            "wrong_fields": (
                json.dumps({"token": 5, "operator_cmd": {"command": "FLIP", "seq": 1}}).encode(),
                200,
            ),
            "nan": (
                b'{"token": "t", "direction_cmd": {"active": true, "azimuth": NaN, "speed": 1, "seq": 1}}',
                200,
            ),
            "huge": (json.dumps({"token": "t", "pad": "x" * 200_000}).encode(), 200),
            "status": (b'{"detail": "boom"}', 500),
            "html": (b"<html>proxy error</html>", 502),
            "partial_cmd": (json.dumps({"token": "t", "operator_cmd": {"command": "LAND"}}).encode(), 200),
        }[self.server.mode]


class GarbageServer(http.server.ThreadingHTTPServer):
    """The broken station's server: ``mode`` picks the garbage its handler replies."""

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Garbage)
        self.mode = ""


def _serving(srv: S) -> Iterator[S]:
    """``srv`` serving on a thread for a fixture's lifetime."""
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    yield srv
    srv.shutdown()
    srv.server_close()


@pytest.fixture
def garbage_server() -> Iterator[GarbageServer]:
    yield from _serving(GarbageServer())


@pytest.mark.parametrize("mode", ["bad_json", "wrong_fields", "nan", "huge", "status", "html", "partial_cmd"])
def test_garbage_replies_are_ignored_and_retried(
    garbage_server: GarbageServer, mode: str, caplog: pytest.LogCaptureFixture
) -> None:
    garbage_server.mode = mode
    node, ctx, got = make_osc(f"http://127.0.0.1:{garbage_server.server_address[1]}", max_reply_bytes=65536)
    try:
        feed_state(ctx)
        assert wait_for(lambda: node.failures >= 3, 10), "keeps retrying"
        assert node.reports_ok == 0 and node.token is None
        assert got == {"cmd": [], "dir": [], "payload": []}, "nothing invented from an invalid reply"
        assert node.reporting
    finally:
        node.stop()
        ctx.close()


def test_many_oscs_share_the_loop_and_send_nothing_once_stopped(station: StationServer) -> None:
    """A process of 40 agents reports through one event loop (no thread per OSC: antalate agent
    --agents 1000 with a station would have started a thousand), and a stopped OSC sends no more."""
    cfgs = [
        parse_config(
            {
                "agent": {"name": f"uav-{i}"},
                "buses": {"lan": "memq://"},
                "osc": {"enabled": True, "server": station.url, "rate": 5.0, "timeout": 2.0},
            }
        )
        for i in range(40)
    ]
    ctx = Context(Buses(cfgs[0].buses), Executor())
    ctx.executor.start()
    threads = threading.active_count()
    nodes = [OscNode(cfg, ctx) for cfg in cfgs]
    try:
        for node in nodes:
            node.start()
        assert wait_for(lambda: all(n.reports_ok >= 2 for n in nodes), 20), [n.failures for n in nodes]
        assert {n.token is not None for n in nodes} == {True}
        # one TLS context for the process (each client's own cost 850 KiB and 17 ms to build)
        assert {id(n._verify) for n in nodes} == {id(tls_context(""))}
        # asyncio's resolver pool at most (a few threads for the whole process), never one per agent
        assert threading.active_count() - threads <= 8, [t.name for t in threading.enumerate()]
        for node in nodes[:20]:
            node.stop()
        stopped = [n.reports_ok for n in nodes[:20]]
        running = [n.reports_ok for n in nodes[20:]]
        assert wait_for(
            lambda: all(n.reports_ok >= r + 2 for n, r in zip(nodes[20:], running, strict=True)), 10
        )
        assert [n.reports_ok for n in nodes[:20]] == stopped
        assert not any(n.reporting for n in nodes[:20]) and all(n.reporting for n in nodes[20:])
    finally:
        for node in nodes:
            node.stop()
        ctx.close()


def test_an_unexpected_error_in_the_exchange_is_logged_and_retried(caplog: pytest.LogCaptureFixture) -> None:
    """Not a server problem but a failure nobody foresaw (here the transport itself raises): the OSC
    says so with the traceback, backs off and keeps reporting, where a thread or task would have died."""
    calls: list[int] = []

    def broken(request: httpx.Request) -> httpx.Response:
        calls.append(1)
        raise RuntimeError("a bug in the transport")

    cfg = parse_config(
        {
            "agent": {"name": "alpha"},
            "buses": {"lan": "memq://"},
            "osc": {"enabled": True, "server": "http://127.0.0.1:9", "rate": 20.0, "max_backoff": 0.2},
        }
    )
    ctx = Context(Buses(cfg.buses), Executor())
    ctx.executor.start()
    node = OscNode(cfg, ctx, transport=httpx.MockTransport(broken))
    try:
        with caplog.at_level(logging.ERROR, logger=node.log.name):
            node.start()
            assert wait_for(lambda: len(calls) >= 3, 5)
        assert node.reporting and node.failures >= 2 and node.reports_ok == 0
        assert "a bug in the transport" in caplog.text and "retrying in 0.2 s" in caplog.text
    finally:
        node.stop()
        ctx.close()


def test_server_down_backs_off_and_recovers(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    node, ctx, got = make_osc(f"http://127.0.0.1:{port}")
    try:
        feed_state(ctx)
        assert wait_for(lambda: node.failures >= 2, 10)
        assert node.token is None
        settings = StationSettings(db_path=str(tmp_path / "s.sqlite"))
        with StationServer(settings, port=port) as srv:
            assert srv.port == port
            assert wait_for(lambda: node.token, 10), "reconnects once the server is up"
            assert node.consecutive_failures == 0
    finally:
        node.stop()
        ctx.close()


def test_server_that_hangs_times_out() -> None:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(16)  # accepts connections, never answers
    try:
        node, ctx, got = make_osc(f"http://127.0.0.1:{listener.getsockname()[1]}", timeout=0.3)
        try:
            feed_state(ctx)
            assert wait_for(lambda: node.failures >= 2, 10)
            assert got["cmd"] == [] and node.token is None
            t0 = time.monotonic()
            node.stop()
            assert time.monotonic() - t0 < 2.0, "stopping does not wait for a hung server"
        finally:
            node.stop()
            ctx.close()
    finally:
        listener.close()


# ----------------------------------------------------------------------------- a station that lies


class _Liar(_FakeStation):
    """A compromised station: its replies come from ``server.replies`` in turn, then empty ones."""

    def reply(self) -> tuple[bytes, int]:
        assert isinstance(self.server, LiarServer)
        replies = self.server.replies
        return json.dumps(replies.pop(0) if replies else {"token": "t"}).encode(), 200


class LiarServer(http.server.ThreadingHTTPServer):
    """The lying station's server: the replies its handler hands out, in turn."""

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Liar)
        self.replies: list[dict[str, Any]] = []


@pytest.fixture
def liar() -> Iterator[LiarServer]:
    yield from _serving(LiarServer())


KEY = generate_key()


def signed_cmd(
    command: str = "LAND", *, target: str = "alpha", age: float = 0.0, key: str = KEY, seq: int = 7
) -> dict[str, Any]:
    msg = build_operator_cmd(
        command, target=target, sender="console", seq=seq, utime=int((time.time() - age) * 1e6), key=key
    )
    return operator_cmd_wire(msg)


def test_a_lying_station_cannot_make_up_retarget_or_replay_commands(
    liar: LiarServer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    good = signed_cmd("LAND", seq=7)
    forged = {**signed_cmd("TAKEOFF", seq=8), "mac": "00" * 32}
    tampered = {**signed_cmd("TAKEOFF", seq=9), "command": "RTL"}  # valid MAC of another message
    retargeted = signed_cmd("TAKEOFF", target="bravo", seq=10)
    stale = signed_cmd("TAKEOFF", age=60.0, seq=11)
    other_swarm = signed_cmd("TAKEOFF", key=generate_key(), seq=12)
    unsigned = {"command": "TAKEOFF", "seq": 13}
    unsigned_dir = {"active": True, "azimuth": 90.0, "speed": 5.0, "seq": 14}
    liar.replies = [
        {"token": "t", "operator_cmd": c}
        for c in (
            unsigned,
            forged,
            tampered,
            retargeted,
            stale,
            other_swarm,
            good,
            good,
        )
    ]
    liar.replies.append({"token": "t", "direction_cmd": unsigned_dir})
    node, ctx, got = make_osc(f"http://127.0.0.1:{liar.server_address[1]}", security={"swarm_key": KEY})
    try:
        assert wait_for(lambda: not liar.replies and node.reports_ok >= 10, 10)
        time.sleep(0.3)
        assert [(m.header.seq, m.header.agent, m.command) for m in got["cmd"]] == [
            (7, "console", operator_cmd_t.LAND)
        ], "only the operator's own command, once"
        assert got["cmd"][0].header.mac == bytes.fromhex(good["mac"]), "published exactly as signed"
        assert got["dir"] == []
        assert node.dropped == {"unsigned": 2, "forged": 3, "retargeted": 1, "stale": 1, "replayed": 1}
        forged_lines = [r for r in caplog.records if "bad MAC" in r.getMessage()]
        assert len(forged_lines) == 1, "three forgeries, one log line (rate-limited)"
        assert node.reporting
    finally:
        node.stop()
        ctx.close()


def test_without_a_key_station_commands_pass_unsigned(liar: LiarServer) -> None:
    liar.replies = [{"token": "t", "operator_cmd": {"command": "RTL", "seq": 3}}]
    node, ctx, got = make_osc(f"http://127.0.0.1:{liar.server_address[1]}")
    try:
        assert wait_for(lambda: got["cmd"], 5)
        assert got["cmd"][0].header.mac_len == 0, "the OSC does not sign for the station"
        assert got["cmd"][0].header.seq == 3 and got["cmd"][0].header.agent == "alpha"
    finally:
        node.stop()
        ctx.close()


@pytest.mark.parametrize(
    ("reply", "words"),
    [
        ({"operator_cmd": {"command": "TAKEOFF", "altitude": 1e9, "seq": 1}}, "altitude"),
        ({"direction_cmd": {"active": True, "azimuth": 400.0, "speed": 1.0, "seq": 1}}, "azimuth"),
        ({"direction_cmd": {"active": True, "azimuth": 10.0, "speed": 1e6, "seq": 1}}, "speed"),
        ({"operator_cmd": {"command": "LAND", "seq": 1, "mac": "ab" * 32}}, "signed command carries all"),
        ({"payload": {"content_type": "", "data": "x"}}, "content_type"),
        ({"payload": {"content_type": "a/b", "data": "!!", "encoding": "base64"}}, "base64"),
    ],
)
def test_out_of_range_replies_are_rejected_with_a_reason(reply: dict[str, Any], words: str) -> None:
    with pytest.raises(wire.ReplyError, match=words):
        wire.parse_reply(json.dumps({"token": "t", **reply}).encode())


# ----------------------------------------------------------------------------- registration and tokens


def test_registration_with_proof_and_token_file(tmp_path: Path) -> None:
    settings = StationSettings(
        db_path=str(tmp_path / "s.sqlite"), api_keys=API_KEYS, registration_key=registration_key(KEY)
    )
    token_file = tmp_path / "osc" / "alpha.token"
    with StationServer(settings) as srv:
        node, ctx, _ = make_osc(srv.url, security={"swarm_key": KEY}, token_file=str(token_file))
        try:
            assert wait_for(lambda: node.token, 5)
            first = node.token
        finally:
            node.stop()
            ctx.close()
        assert token_file.read_text().strip() == first and token_file.stat().st_mode & 0o777 == 0o600
        # A restart with the file: same token, no new registration.
        node, ctx, _ = make_osc(srv.url, security={"swarm_key": KEY}, token_file=str(token_file))
        try:
            assert node.token == first
            assert wait_for(lambda: node.reports_ok >= 3, 5) and node.token == first
        finally:
            node.stop()
            ctx.close()
        # A restart that lost the file proves the key again and gets a new token for the same agent.
        token_file.unlink()
        node, ctx, _ = make_osc(srv.url, security={"swarm_key": KEY}, token_file=str(token_file))
        try:
            assert wait_for(lambda: node.token and node.token != first, 5)
        finally:
            node.stop()
            ctx.close()
        assert [a["name"] for a in httpx.get(f"{srv.url}/api/agents", headers=AUTH).json()] == ["alpha"]
        # Without the key the name cannot be taken: 401 (no proof), never a token.
        node, ctx, _ = make_osc(srv.url)
        try:
            assert wait_for(lambda: node.failures >= 2, 5) and node.token is None
        finally:
            node.stop()
            ctx.close()


def test_a_void_token_is_dropped_and_the_osc_registers_again(tmp_path: Path) -> None:
    settings = StationSettings(db_path=str(tmp_path / "s.sqlite"), registration_key=registration_key(KEY))
    token_file = tmp_path / "alpha.token"
    token_file.write_text("a-token-from-a-station-whose-database-was-reset\n")
    with StationServer(settings) as srv:
        node, ctx, _ = make_osc(srv.url, security={"swarm_key": KEY}, token_file=str(token_file))
        try:
            assert wait_for(lambda: node.reports_ok >= 1, 10), "re-registered after the 401"
            assert node.failures >= 1 and token_file.read_text().strip() == node.token
        finally:
            node.stop()
            ctx.close()


def test_the_osc_waits_as_long_as_retry_after_says(tmp_path: Path) -> None:
    from antalate_lcm.station._settings import RateLimits

    limits = RateLimits(reports_per_second=0.5, report_burst=1)
    with StationServer(StationSettings(db_path=str(tmp_path / "s.sqlite"), rate_limits=limits)) as srv:
        node, ctx, _ = make_osc(srv.url)  # reports at 20 Hz, max_backoff 0.5 s
        try:
            assert wait_for(lambda: node.failures >= 1, 5)
            t0, failures = time.monotonic(), node.failures
            assert wait_for(lambda: node.failures > failures or node.reports_ok >= 3, 10)
            assert time.monotonic() - t0 >= 0.9, "Retry-After (whole seconds) outweighs a shorter backoff"
        finally:
            node.stop()
            ctx.close()


# ----------------------------------------------------------------------------- TLS


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI")
def test_tls_station_and_osc_with_a_ca_file(tmp_path: Path) -> None:
    ca, cert, key = make_tls(tmp_path)
    settings = StationSettings(db_path=str(tmp_path / "s.sqlite"), api_keys=API_KEYS)
    with StationServer(settings, tls_cert=str(cert), tls_key=str(key)) as srv:
        assert srv.url.startswith("https://127.0.0.1:")
        node, ctx, got = make_osc(srv.url, ca_file=str(ca))
        try:
            feed_state(ctx)
            assert wait_for(lambda: node.token, 5), "the OSC trusts the station through its CA"
            with StationClient(srv.url, OPERATOR_KEY, ca_file=str(ca)) as c:
                assert [a["name"] for a in c.agents()] == ["alpha"]
                c.command("RTL", target="alpha")
            assert wait_for(lambda: got["cmd"], 5)
        finally:
            node.stop()
            ctx.close()
        stranger, ctx2, _ = make_osc(srv.url)  # no ca_file: the system CAs do not know this one
        try:
            assert wait_for(lambda: stranger.failures >= 2, 5) and stranger.token is None
        finally:
            stranger.stop()
            ctx2.close()
        with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
            httpx.get(f"{srv.url}/api/station")
    with pytest.raises(AntalateError, match="TLS"):
        StationServer(settings, tls_cert=str(cert))
    with pytest.raises(AntalateError, match="cannot use TLS certificate"):
        StationServer(settings, tls_cert=str(ca), tls_key=str(key))  # a key that is not the certificate's


def test_a_missing_ca_file_is_a_config_error(tmp_path: Path) -> None:
    cfg = parse_config(
        {
            "agent": {"name": "alpha"},
            "buses": {"lan": "memq://"},
            "osc": {"enabled": True, "server": "https://127.0.0.1:1", "ca_file": str(tmp_path / "no.pem")},
        }
    )
    ctx = Context(Buses(cfg.buses), Executor())
    with pytest.raises(ConfigError, match="osc.ca_file"):
        OscNode(cfg, ctx)
    ctx.close()


# ----------------------------------------------------------------------------- end to end over multicast


@pytest.mark.netns
def test_a_signed_command_through_the_station_flies_a_real_agent(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    """Station, agent (MC, HLC, OSC) and `antalate command` as separate processes on real multicast."""
    api_key, swarm_file, key_file = (
        "antk_e2e-operator-key-0123456789abcdefghijklmn",
        tmp_path / "swarm.key",
        tmp_path / "api.key",
    )
    swarm_file.write_text(KEY)
    key_file.write_text(api_key)
    station_cfg = tmp_path / "station.toml"
    station_cfg.write_text(
        f'[station]\nhost = "127.0.0.1"\nport = 8080\ndb = ":memory:"\nregistration_key = "{registration_key(KEY)}"\n'
        f'[[api_keys]]\nname = "e2e"\nrole = "operator"\nsha256 = "{sha256_hex(api_key)}"\n'
    )
    station_log = open(tmp_path / "station.log", "w")  # noqa: SIM115 - closed below
    netns.antalate("station", "--config", str(station_cfg), stdout=station_log, stderr=subprocess.STDOUT)
    agent = AgentProcesses(
        netns,
        tmp_path,
        agent_config(
            "alpha",
            security={"swarm_key": KEY},
            osc={"enabled": True, "server": "http://127.0.0.1:8080", "rate": 5.0},
        ),
    )
    agent.start("agent")
    base = [
        sys.executable,
        "-m",
        "antalate_lcm.cli",
        "command",
        "--station",
        "http://127.0.0.1:8080",
        "--api-key-file",
        str(key_file),
    ]
    try:
        assert probe.wait("alpha/MC_STATE", "mc_state_t", timeout=20, state=mc_state_t.STANDBY)

        def queued() -> dict[str, Any] | None:
            r = netns.run([*base, "TAKEOFF", "--target", "alpha", "--swarm-key-file", str(swarm_file)])
            return json.loads(r.stdout) if r.returncode == 0 else None  # 404 until the OSC registered

        reply = wait_for(queued, 20)
        assert reply, "the station never knew alpha"
        seq = reply["queued"][0]["operator_cmd"]["seq"]
        msg = probe.wait("alpha/MC_STATE", "mc_state_t", timeout=20, last_command_seq=seq)
        assert msg is not None, "the MC never accepted the signed command"
        assert msg["state"] in (mc_state_t.TAKEOFF, mc_state_t.MISSION)
        # An unsigned command does not even get queued on a station whose agents hold a key.
        r = netns.run([*base, "LAND", "--target", "alpha"])
        assert r.returncode == 2 and "sign" in r.stderr
        listing = netns.run([*base, "agents"])
        assert listing.returncode == 0 and '"token"' not in listing.stdout
    finally:
        codes = agent.stop()
        station_log.close()
    assert all(c in (0, -15, None) for c in codes.values()), codes
    assert "Traceback" not in agent.log("agent")
