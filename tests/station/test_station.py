"""The station over real HTTP: uvicorn on 127.0.0.1 (a free port), a real SQLite file, httpx.

Geometry is checked against a tangent-plane model written in `test_station_sector` (independent
of the station's code): peers are placed at chosen ranges and bearings, and the station's answer
must match them within millimetres and hundredths of a degree.
"""

from __future__ import annotations

import json
import socket
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.station import StationServer, StationSettings, default_db_path, models, run_station
from antalate_lcm.station._auth import sha256_hex
from antalate_lcm.station._settings import ApiKey
from tests import REPO
from tests.station.test_station_sector import place

ORIGIN = (32.7767, 35.0231)
OPERATOR_KEY = "antk_test-operator-key-0123456789abcdefghijklmnopq"
READER_KEY = "antk_test-reader-key-0123456789abcdefghijklmnopqrs"
API_KEYS = (
    ApiKey(name="op", role="operator", sha256=sha256_hex(OPERATOR_KEY)),
    ApiKey(name="viewer", role="read-only", sha256=sha256_hex(READER_KEY)),
)
AUTH = {"Authorization": f"Bearer {OPERATOR_KEY}"}


def settings_for(db_path: str, **fields: Any) -> StationSettings:
    """Station settings with the test API keys (every test station has them)."""
    return StationSettings(db_path=db_path, api_keys=API_KEYS, **fields)


def operator_client(url: str, **kw: Any) -> httpx.Client:
    return httpx.Client(base_url=url, timeout=5.0, headers=AUTH, **kw)


def agent_ids(c: httpx.Client) -> dict[str, str]:
    return {a["name"]: a["id"] for a in c.get("/api/agents").json()}


@pytest.fixture
def db_path(tmp_path: Path) -> str:
    return str(tmp_path / "station.sqlite")


@pytest.fixture
def server(db_path: str) -> Iterator[StationServer]:
    settings = settings_for(db_path, range_m=100.0, fov_deg=60.0, stale_after_s=30.0)
    with StationServer(settings) as srv:
        yield srv


@pytest.fixture
def client(server: StationServer) -> Iterator[httpx.Client]:
    with operator_client(server.url) as c:
        yield c


def tel(
    lat: float, lon: float, heading: float = 0.0, agent: str | None = None, **extra: Any
) -> dict[str, Any]:
    t: dict[str, Any] = {
        "lat": lat,
        "lon": lon,
        "heading": heading,
        "alt": 10.0,
        "vn": 0.0,
        "ve": 0.0,
        "vd": 0.0,
        "battery": 90.0,
        "armed": True,
        "in_air": True,
        "mode": "SIM",
        **extra,
    }
    if agent is not None:
        t["agent"] = agent
    return t


def report(
    c: httpx.Client, token: str | None = None, telemetry: dict[str, Any] | None = None, **fields: Any
) -> dict[str, Any]:
    body = {
        "token": token,
        "mc_state": "MISSION",
        "hlc_state": "AIRBORNE",
        "telemetry": telemetry,
        "feedback": None,
        **fields,
    }
    r = c.post("/api/report", json=body)
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


def detection(reply: dict[str, Any]) -> dict[str, Any]:
    payload = reply["payload"]
    assert payload["content_type"] == "application/json"
    found: dict[str, Any] = json.loads(payload["data"])
    return found


# -- tokens ------------------------------------------------------------------------------------------


def test_first_contact_gets_a_token_that_is_kept(client: httpx.Client) -> None:
    first = report(client, None, tel(*ORIGIN, agent="uav1"))
    token = first["token"]
    assert isinstance(token, str) and len(token) >= 16
    assert "operator_cmd" not in first and "direction_cmd" not in first
    again = report(client, token, tel(*ORIGIN, agent="uav1"))
    assert again["token"] == token
    # A body without the token key at all is first contact too.
    other = client.post("/api/report", json={"telemetry": tel(*ORIGIN, agent="uav2")}).json()
    assert other["token"] != token
    agents = client.get("/api/agents").json()
    assert [a["name"] for a in agents] == ["uav1", "uav2"]
    assert all("token" not in a for a in agents), "tokens are secrets, never listed"
    assert (
        token not in client.get("/api/agents").text and other["token"] not in client.get("/api/agents").text
    )
    uav1 = agents[0]
    assert uav1["mc_state"] == "MISSION" and uav1["hlc_state"] == "AIRBORNE" and not uav1["stale"]
    assert uav1["telemetry"]["lat"] == ORIGIN[0] and uav1["telemetry"]["battery"] == 90.0
    assert uav1["first_seen"] <= uav1["last_seen"] and uav1["pending_commands"] == 0


def test_unknown_token_is_401_and_never_adopted(client: httpx.Client) -> None:
    r = client.post(
        "/api/report", json={"token": "not-a-token-this-station-issued", "telemetry": tel(*ORIGIN)}
    )
    assert r.status_code == 401 and "unknown token" in r.json()["detail"]
    assert client.get("/api/agents").json() == []


def test_report_without_telemetry_registers_but_has_no_payload(client: httpx.Client) -> None:
    reply = report(client, None, None, mc_state="STANDBY", hlc_state=None)
    assert "payload" not in reply
    (agent,) = client.get("/api/agents").json()
    assert agent["name"] == agent["id"]  # no name heard: the public id stands in
    assert agent["mc_state"] == "STANDBY" and agent["hlc_state"] is None and agent["telemetry"] is None


# -- commands ----------------------------------------------------------------------------------------


def test_command_to_one_agent_is_delivered_once(client: httpx.Client) -> None:
    a = report(client, None, tel(*ORIGIN, agent="a"))["token"]
    b = report(client, None, tel(*ORIGIN, agent="b"))["token"]
    r = client.post("/api/commands", json={"command": "TAKEOFF", "altitude": 15.0, "target": "a"})
    assert r.status_code == 200, r.text
    queued = r.json()
    assert queued["target"] == "a" and [q["name"] for q in queued["queued"]] == ["a"]
    seq = queued["seq"]
    assert client.get("/api/agents").json()[0]["pending_commands"] == 1
    assert "operator_cmd" not in report(client, b, tel(*ORIGIN))
    got = report(client, a, tel(*ORIGIN))
    assert got["operator_cmd"] == {"command": "TAKEOFF", "altitude": 15.0, "seq": seq}
    assert "operator_cmd" not in report(client, a, tel(*ORIGIN))


def test_command_by_id_and_without_altitude(client: httpx.Client) -> None:
    a = report(client, None, tel(*ORIGIN, agent="a"))["token"]
    r = client.post("/api/commands", json={"command": "RTL", "target": agent_ids(client)["a"]})
    assert r.status_code == 200
    assert report(client, a, None)["operator_cmd"] == {"command": "RTL", "seq": r.json()["seq"]}


def test_command_for_all_reaches_each_known_agent_once_and_not_later_ones(client: httpx.Client) -> None:
    tokens = [report(client, None, tel(*ORIGIN, agent=f"u{i}"))["token"] for i in range(3)]
    r = client.post("/api/commands", json={"command": "LAND"})
    assert r.status_code == 200
    body = r.json()
    assert body["target"] is None and sorted(q["name"] for q in body["queued"]) == ["u0", "u1", "u2"]
    late = report(client, None, tel(*ORIGIN, agent="late"))
    assert "operator_cmd" not in late
    for tok in tokens:
        assert report(client, tok, tel(*ORIGIN))["operator_cmd"]["command"] == "LAND"
        assert "operator_cmd" not in report(client, tok, tel(*ORIGIN))
    assert "operator_cmd" not in report(client, late["token"], tel(*ORIGIN))


def test_operator_commands_queue_in_order_and_seq_increases(client: httpx.Client) -> None:
    a = report(client, None, tel(*ORIGIN, agent="a"))["token"]
    s1 = client.post("/api/commands", json={"command": "TAKEOFF", "target": "a"}).json()["seq"]
    s2 = client.post("/api/commands", json={"command": "LAND", "target": "a"}).json()["seq"]
    assert s2 > s1
    assert report(client, a, None)["operator_cmd"] == {"command": "TAKEOFF", "seq": s1}
    assert report(client, a, None)["operator_cmd"] == {"command": "LAND", "seq": s2}
    assert "operator_cmd" not in report(client, a, None)


def test_latest_direction_replaces_a_pending_one(client: httpx.Client) -> None:
    a = report(client, None, tel(*ORIGIN, agent="a"))["token"]
    client.post("/api/commands", json={"direction": {"azimuth": 10.0, "speed": 3.0}, "target": "a"})
    op = client.post("/api/commands", json={"command": "RTL", "target": "a"}).json()["seq"]
    newer = client.post("/api/commands", json={"direction": {"azimuth": -90.0, "speed": 1.5, "active": True}})
    assert newer.status_code == 200
    seq = newer.json()["seq"]
    got = report(client, a, tel(*ORIGIN))
    assert got["direction_cmd"] == {"active": True, "azimuth": 270.0, "speed": 1.5, "seq": seq}
    assert got["operator_cmd"] == {"command": "RTL", "seq": op}
    again = report(client, a, tel(*ORIGIN))
    assert "direction_cmd" not in again and "operator_cmd" not in again
    off = client.post("/api/commands", json={"direction": {"azimuth": 0, "speed": 0, "active": False}}).json()
    assert report(client, a, None)["direction_cmd"]["active"] is False
    assert off["queued"][0]["direction_cmd"]["active"] is False


def test_command_to_unknown_target_is_404(client: httpx.Client) -> None:
    r = client.post("/api/commands", json={"command": "LAND", "target": "nobody"})
    assert r.status_code == 404
    assert "nobody" in r.json()["detail"]


def test_commands_for_all_with_no_agent_queue_nothing(client: httpx.Client) -> None:
    r = client.post("/api/commands", json={"command": "RTL"})
    assert r.status_code == 200 and r.json()["queued"] == []


def test_commands_not_collected_in_time_expire(db_path: str) -> None:
    settings = settings_for(db_path, command_ttl_s=0.2)
    with StationServer(settings) as srv, operator_client(srv.url) as c:
        a = report(c, None, tel(*ORIGIN, agent="a"))["token"]
        c.post("/api/commands", json={"command": "TAKEOFF", "target": "a"})
        c.post("/api/commands", json={"direction": {"azimuth": 1, "speed": 1}, "target": "a"})
        time.sleep(0.3)
        reply = report(c, a, None)
        assert "operator_cmd" not in reply and "direction_cmd" not in reply
    with sqlite3.connect(db_path) as conn:
        assert sorted(r[0] for r in conn.execute("SELECT state FROM deliveries")) == ["expired", "expired"]


# -- peer detection ----------------------------------------------------------------------------------


def register_peer(
    c: httpx.Client, dist: float, bearing: float, heading: float = 0.0, origin: tuple[float, float] = ORIGIN
) -> tuple[float, float]:
    lat, lon = place(*origin, dist, bearing)
    report(c, None, tel(lat, lon, heading))
    return lat, lon


@pytest.mark.parametrize(
    ("heading", "dist", "bearing", "expected_rel"),
    [
        (0.0, 50.0, 10.0, 10.0),  # in front, a little right
        (90.0, 80.0, 60.5, -29.5),  # near the left edge (fov 60 → ±30), just inside
        (350.0, 40.0, 10.0, 20.0),  # heading wraps around north
        (10.0, 40.0, 350.0, -20.0),
        (200.0, 99.5, 200.0, 0.0),  # just inside the range, dead ahead
    ],
)
def test_peer_inside_the_front_sector(
    client: httpx.Client, heading: float, dist: float, bearing: float, expected_rel: float
) -> None:
    register_peer(client, dist, bearing)
    d = detection(report(client, None, tel(*ORIGIN, heading)))
    assert d["detected"] is True and d["count"] == 1
    assert d["nearest_range"] == pytest.approx(dist, abs=0.01)
    assert d["nearest_bearing"] == pytest.approx(expected_rel, abs=0.01)


@pytest.mark.parametrize(
    ("heading", "dist", "bearing"),
    [
        (0.0, 30.0, 180.0),  # behind
        (0.0, 101.0, 0.0),  # dead ahead but out of range
        (0.0, 50.0, 30.5),  # just outside the right edge
        (0.0, 50.0, -30.5),  # just outside the left edge
        (350.0, 40.0, 30.0),  # relative +40 after the wrap
    ],
)
def test_peer_outside_the_front_sector(
    client: httpx.Client, heading: float, dist: float, bearing: float
) -> None:
    register_peer(client, dist, bearing)
    d = detection(report(client, None, tel(*ORIGIN, heading)))
    assert d == {"detected": False, "count": 0, "nearest_range": 0.0, "nearest_bearing": 0.0}


def test_count_and_nearest_among_several_peers(client: httpx.Client) -> None:
    for dist, bearing in ((90.0, 5.0), (35.0, -12.0), (60.0, 25.0), (20.0, 120.0), (150.0, 0.0)):
        register_peer(client, dist, bearing)
    me = report(client, None, tel(*ORIGIN, 0.0))
    d = detection(me)
    assert d["count"] == 3 and d["detected"]
    assert d["nearest_range"] == pytest.approx(35.0, abs=0.01)
    assert d["nearest_bearing"] == pytest.approx(-12.0, abs=0.01)
    # Turning round changes the answer: the reporter's own report moves its heading.
    d = detection(report(client, me["token"], tel(*ORIGIN, 120.0)))
    assert d["count"] == 1 and d["nearest_range"] == pytest.approx(20.0, abs=0.01)
    assert d["nearest_bearing"] == pytest.approx(0.0, abs=0.01)


def test_stale_agents_are_not_detected(db_path: str) -> None:
    settings = settings_for(db_path, stale_after_s=0.4)
    with StationServer(settings) as srv, operator_client(srv.url) as c:
        register_peer(c, 30.0, 0.0)
        me = report(c, None, tel(*ORIGIN, 0.0))
        assert detection(me)["detected"] is True
        time.sleep(0.6)
        assert detection(report(c, me["token"], tel(*ORIGIN, 0.0)))["detected"] is False
        assert sorted(a["stale"] for a in c.get("/api/agents").json()) == [False, True]


# -- persistence -------------------------------------------------------------------------------------


def test_restart_with_the_same_database_keeps_agents_tokens_and_commands(db_path: str) -> None:
    settings = settings_for(db_path, stale_after_s=60.0)
    with StationServer(settings) as srv, operator_client(srv.url) as c:
        register_peer(c, 40.0, 0.0)
        me = report(
            c, None, tel(*ORIGIN, 0.0, agent="me"), feedback={"content_type": "text/plain", "data": "hi"}
        )
        token = me["token"]
        seq = c.post("/api/commands", json={"command": "TAKEOFF", "target": "me"}).json()["seq"]
        before = c.get("/api/agents").json()
    with StationServer(settings) as srv, operator_client(srv.url) as c:
        after = c.get("/api/agents").json()
        assert [(a["id"], a["name"], a["telemetry"]) for a in after] == [
            (a["id"], a["name"], a["telemetry"]) for a in before
        ]
        assert {a["name"]: a["pending_commands"] for a in after}["me"] == 1
        again = report(c, token, tel(*ORIGIN, 0.0))
        assert again["token"] == token
        assert again["operator_cmd"] == {"command": "TAKEOFF", "seq": seq}
        d = detection(again)  # the peer's position was restored into the index
        assert d["count"] == 1 and d["nearest_range"] == pytest.approx(40.0, abs=0.01)
        seq2 = c.post("/api/commands", json={"command": "LAND"}).json()["seq"]
        assert seq2 > seq  # sequence numbers are never reused across restarts
    with sqlite3.connect(db_path) as conn:
        rows = conn.execute(
            "SELECT agent_id, lat, feedback_type, feedback_data FROM reports ORDER BY id"
        ).fetchall()
    assert len(rows) == 3  # every report is in the history, flushed on shutdown
    me_id = {a["name"]: a["id"] for a in before}["me"]
    assert rows[1] == (me_id, ORIGIN[0], "text/plain", "hi")


def test_feedback_in_base64(client: httpx.Client) -> None:
    fb = {"content_type": "image/png", "data": "iVBORw0KGgo=", "encoding": "base64"}
    report(client, None, tel(*ORIGIN), feedback=fb)
    bad = client.post("/api/report", json={"telemetry": None, "feedback": {**fb, "data": "not base64!"}})
    assert bad.status_code == 422 and "base64" in bad.json()["detail"]


def test_memory_database_works(tmp_path: Path) -> None:
    with StationServer(settings_for(":memory:")) as srv, operator_client(srv.url) as c:
        report(c, None, tel(*ORIGIN, agent="m"))
        assert c.post("/api/commands", json={"command": "RTL"}).json()["queued"][0]["name"] == "m"


# -- bad input -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "status", "words"),
    [
        (b"garbage", 422, "not valid JSON"),
        (b'{"token": null, "telemetry": {"lat": 32', 422, "not valid JSON"),
        (b"[1, 2]", 422, "object"),
        (b'{"telemetry": {"lat": NaN, "lon": 35.0, "heading": 0}}', 422, "telemetry.lat"),
        (b'{"telemetry": {"lat": "32.1", "lon": 35.0, "heading": 0}}', 422, "telemetry.lat"),
        (b'{"telemetry": {"lat": 91.0, "lon": 35.0, "heading": 0}}', 422, "telemetry.lat"),
        (b'{"telemetry": {"lat": 32.0, "lon": 35.0}}', 422, "telemetry.heading"),
        (b'{"telemetry": {"lat": 32.0, "lon": 35.0, "heading": 0, "armed": "yes"}}', 422, "telemetry.armed"),
        (b'{"mc_state": "FLYING"}', 422, "mc_state"),
        (b'{"token": 12}', 422, "token"),
        (b'{"feedback": {"data": "x"}}', 422, "feedback.content_type"),
    ],
)
def test_bad_reports_get_a_4xx_with_a_reason(
    client: httpx.Client, body: bytes, status: int, words: str
) -> None:
    r = client.post("/api/report", content=body, headers={"content-type": "application/json"})
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert words in detail, detail
    assert r.json()["errors"]
    # The station keeps serving.
    assert report(client, None, tel(*ORIGIN))["token"]


def test_report_needs_a_json_content_type(client: httpx.Client) -> None:
    r = client.post("/api/report", content=b"{}", headers={"content-type": "text/plain"})
    assert r.status_code == 415 and "application/json" in r.json()["detail"]
    # No content type at all is accepted (curl -d, tiny scripts).
    r = client.post("/api/report", content=b"{}")
    assert r.status_code == 200


def test_oversized_request_is_413(db_path: str) -> None:
    settings = settings_for(db_path, max_body_bytes=4096)
    with StationServer(settings) as srv, operator_client(srv.url) as c:
        big = {"feedback": {"content_type": "text/plain", "data": "x" * 10_000}}
        r = c.post("/api/report", json=big)
        assert r.status_code == 413 and "4096" in r.json()["detail"]

        def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it arrives
            yield b'{"feedback": {"content_type": "text/plain", "data": "'
            for _ in range(10):
                yield b"x" * 1000
            yield b'"}}'

        r = c.post("/api/report", content=chunks(), headers={"content-type": "application/json"})
        assert r.status_code == 413
        assert report(c, None, tel(*ORIGIN))["token"]


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ({}, "exactly one"),
        ({"command": "RTL", "direction": {"azimuth": 0, "speed": 1}}, "exactly one"),
        ({"command": "FLIP"}, "command"),
        ({"command": "LAND", "altitude": 10}, "altitude"),
        ({"command": "TAKEOFF", "altitude": -1}, "altitude"),
        ({"direction": {"azimuth": 0, "speed": -1}}, "direction.speed"),
        ({"direction": {"azimuth": "north", "speed": 1}}, "direction.azimuth"),
        ({"direction": {"speed": 1}}, "direction.azimuth"),
        ({"command": "RTL", "target": ""}, "target"),
        ({"direction": {"azimuth": 0, "speed": 101}}, "direction.speed"),
        ({"command": "TAKEOFF", "altitude": 1e9}, "altitude"),
    ],
)
def test_bad_commands_get_422(client: httpx.Client, body: dict[str, Any], words: str) -> None:
    r = client.post("/api/commands", json=body)
    assert r.status_code == 422, r.text
    assert words in r.json()["detail"], r.json()


def test_bad_json_command_is_422(client: httpx.Client) -> None:
    r = client.post("/api/commands", content=b"{nope", headers={"content-type": "application/json"})
    assert r.status_code == 422 and "not valid JSON" in r.json()["detail"]


# -- protocol document and contracts ---------------------------------------------------------------------


def test_openapi_document_is_served_and_committed_copy_is_current(client: httpx.Client) -> None:
    served = client.get("/openapi.json").json()
    report_op = served["paths"]["/api/report"]["post"]
    assert report_op["requestBody"]["content"]["application/json"]["schema"]["$ref"].endswith(
        "/ReportRequest"
    )
    assert {"/api/report", "/api/agents", "/api/commands"} <= set(served["paths"])
    for name in (
        "ReportRequest",
        "ReportReply",
        "OperatorCommand",
        "DirectionCommand",
        "Payload",
        "PeerDetection",
    ):
        assert name in served["components"]["schemas"], name
    committed = json.loads((REPO / "docs" / "openapi.json").read_text())
    assert committed == served, (
        "docs/openapi.json is stale: python -m antalate_lcm.station.openapi > docs/openapi.json"
    )


def test_peer_detection_has_the_fields_of_peer_detection_t() -> None:
    from antalate_lcm.msgs import peer_detection_t

    assert set(models.PeerDetection.model_fields) == set(peer_detection_t.__slots__) - {"header"}


def test_telemetry_has_the_fields_of_telemetry_t() -> None:
    from antalate_lcm.msgs import telemetry_t

    assert set(models.Telemetry.model_fields) == (set(telemetry_t.__slots__) - {"header"}) | {"agent"}


# -- settings and startup errors --------------------------------------------------------------------------


def test_default_db_path_follows_xdg(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    assert default_db_path() == tmp_path / "antalate" / "station.sqlite"
    assert StationSettings().db_path == str(tmp_path / "antalate" / "station.sqlite")
    monkeypatch.delenv("XDG_DATA_HOME")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert default_db_path() == tmp_path / ".local" / "share" / "antalate" / "station.sqlite"


def test_run_station_reports_a_busy_port_and_an_unusable_database(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(AntalateError, match="cannot listen"):
            run_station("127.0.0.1", port, str(tmp_path / "s.sqlite"))
    not_a_db = tmp_path / "junk.sqlite"
    not_a_db.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(AntalateError, match="junk.sqlite"):
        run_station("127.0.0.1", 0, str(not_a_db))
    newer = tmp_path / "newer.sqlite"
    with sqlite3.connect(newer) as conn:
        conn.execute("PRAGMA user_version=99")
    with pytest.raises(AntalateError, match="schema version 99"):
        run_station("127.0.0.1", 0, str(newer))
    with pytest.raises(AntalateError, match="fov_deg"):
        run_station("127.0.0.1", 0, str(tmp_path / "s.sqlite"), fov_deg=400.0)


def test_listening_socket_is_declared_tcp() -> None:
    """asyncio's own loop turns Nagle off on accepted connections only for sockets whose proto is
    IPPROTO_TCP; without it every reply waits ~40 ms for a delayed ACK (uvloop hides this)."""
    from antalate_lcm.station._server import _bind

    sock = _bind("127.0.0.1", 0)
    try:
        assert sock.proto == socket.IPPROTO_TCP
    finally:
        sock.close()


def test_station_info(client: httpx.Client) -> None:
    info = client.get("/api/station").json()
    assert info["range_m"] == 100.0 and info["fov_deg"] == 60.0 and info["agents"] == 0
    assert info["registration_proof"] is False
