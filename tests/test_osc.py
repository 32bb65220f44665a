"""The OSC against the real station, and against servers that are down, hang or answer garbage."""

from __future__ import annotations

import http.server
import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from antalate_lcm.bus import Bus
from antalate_lcm.config import parse_config
from antalate_lcm.executor import Executor
from antalate_lcm.msgs import direction_cmd_t, mc_state_t, operator_cmd_t, payload_t, telemetry_t
from antalate_lcm.node import Context
from antalate_lcm.osc import OscNode
from antalate_lcm.station import StationServer, StationSettings
from tests.netns import wait_for
from tests.test_station import API_KEYS, AUTH


def make_osc(server: str, **osc: Any) -> tuple[OscNode, Context, dict[str, list[Any]]]:
    cfg = parse_config(
        {
            "agent": {"name": "alpha"},
            "buses": {"lan": "memq://"},
            "osc": {"enabled": True, "server": server, "rate": 20.0, "timeout": 0.5, "max_backoff": 0.5, **osc},
        }
    )
    ctx = Context(Bus(cfg.buses), Executor())
    ctx.executor.start()
    got: dict[str, list[Any]] = {"cmd": [], "dir": [], "payload": []}
    ctx.bus.subscribe("lan", "alpha/OPERATOR_CMD", operator_cmd_t, lambda c, m: got["cmd"].append(m))
    ctx.bus.subscribe("lan", "alpha/DIRECTION_CMD", direction_cmd_t, lambda c, m: got["dir"].append(m))
    ctx.bus.subscribe("lan", "alpha/OPERATOR_PAYLOAD", payload_t, lambda c, m: got["payload"].append(m))
    node = OscNode(cfg, ctx)
    node.start()
    return node, ctx, got


def feed_state(ctx: Context, lat: float = 32.0, heading: float = 0.0) -> None:
    mc = mc_state_t()
    mc.state = mc_state_t.MISSION
    ctx.bus.publish("lan", "alpha/MC_STATE", mc)
    t = telemetry_t()
    t.header.agent = "alpha"
    t.lat, t.lon, t.heading, t.battery, t.mode = lat, 35.0, heading, 80.0, "SIM"
    ctx.bus.publish("lan", "alpha/TELEMETRY", t)


@pytest.fixture
def station(tmp_path: Path) -> Iterator[StationServer]:
    settings = StationSettings(db_path=str(tmp_path / "station.sqlite"), range_m=100, fov_deg=60, api_keys=API_KEYS)
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
        r = httpx.post(f"{station.url}/api/commands", json={"command": "RTL", "target": "alpha"}, headers=AUTH)
        assert r.status_code == 200, r.text
        seq = r.json()["seq"]
        assert wait_for(lambda: got["cmd"], 5)
        cmd = got["cmd"][0]
        assert cmd.command == operator_cmd_t.RTL and cmd.header.seq == seq and cmd.target == "alpha"
        httpx.post(f"{station.url}/api/commands", json={"direction": {"azimuth": 90, "speed": 1.5}}, headers=AUTH)
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


class _Garbage(http.server.BaseHTTPRequestHandler):
    mode = "json"

    def log_message(self, *args: Any) -> None:
        pass

    def do_POST(self) -> None:  # noqa: N802 - http.server's API
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        body, status = {
            "bad_json": (b"{not json", 200),
            "wrong_fields": (json.dumps({"token": 5, "operator_cmd": {"command": "FLIP", "seq": 1}}).encode(), 200),
            "nan": (b'{"token": "t", "direction_cmd": {"active": true, "azimuth": NaN, "speed": 1, "seq": 1}}', 200),
            "huge": (json.dumps({"token": "t", "pad": "x" * 200_000}).encode(), 200),
            "status": (b'{"detail": "boom"}', 500),
            "html": (b"<html>proxy error</html>", 502),
            "partial_cmd": (json.dumps({"token": "t", "operator_cmd": {"command": "LAND"}}).encode(), 200),
        }[self.server.mode]  # type: ignore[attr-defined]
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


@pytest.fixture
def garbage_server() -> Iterator[http.server.ThreadingHTTPServer]:
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Garbage)
    th = threading.Thread(target=srv.serve_forever, daemon=True)
    th.start()
    yield srv
    srv.shutdown()
    srv.server_close()


@pytest.mark.parametrize("mode", ["bad_json", "wrong_fields", "nan", "huge", "status", "html", "partial_cmd"])
def test_garbage_replies_are_ignored_and_retried(
    garbage_server: http.server.ThreadingHTTPServer, mode: str, caplog: pytest.LogCaptureFixture
) -> None:
    garbage_server.mode = mode  # type: ignore[attr-defined]
    node, ctx, got = make_osc(f"http://127.0.0.1:{garbage_server.server_address[1]}", max_reply_bytes=65536)
    try:
        feed_state(ctx)
        assert wait_for(lambda: node.failures >= 3, 10), "keeps retrying"
        assert node.reports_ok == 0 and node.token is None
        assert got == {"cmd": [], "dir": [], "payload": []}, "nothing invented from an invalid reply"
        assert node._thread is not None and node._thread.is_alive()
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
