"""The station's defences over real HTTP (uvicorn on 127.0.0.1, a real SQLite file, httpx).

Each test is an attack from the issue or a rule that stops one: operators need an API key with
the right role, tokens are secrets (never listed, hashed at rest), registration proves the swarm
key, names cannot be taken over, requests are rate-limited, and signed commands travel untouched.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from antalate_lcm.agent.osc import wire
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.station import StationServer, StationSettings
from antalate_lcm.station._auth import registration_key, registration_mac, sha256_hex
from antalate_lcm.station._file import load_station_file
from antalate_lcm.station._settings import RateLimits
from antalate_lcm.station.client import StationClient, StationClientError
from antalate_lcm.wire.security import generate_key, verify
from tests.harness.process import run_antalate
from tests.station.test_station import API_KEYS, AUTH, OPERATOR_KEY, ORIGIN, READER_KEY, settings_for, tel

SWARM_KEY = generate_key()
REG_KEY = registration_key(SWARM_KEY)


@pytest.fixture
def db_path(tmp_path: Path) -> str:
    return str(tmp_path / "station.sqlite")


@pytest.fixture
def open_station(db_path: str) -> Iterator[StationServer]:
    """No registration key: any host may register a new name (a trusted network)."""
    with StationServer(settings_for(db_path)) as srv:
        yield srv


@pytest.fixture
def keyed_station(db_path: str) -> Iterator[StationServer]:
    """Registration needs proof of the swarm key; commands must be signed."""
    with StationServer(settings_for(db_path, registration_key=REG_KEY)) as srv:
        yield srv


def post_report(url: str, body: dict[str, Any]) -> httpx.Response:
    return httpx.post(f"{url}/api/report", json=body, timeout=5.0)


def register(url: str, name: str, *, key: str | None = SWARM_KEY, **extra: Any) -> httpx.Response:
    body: dict[str, Any] = {"agent": name, "telemetry": tel(*ORIGIN, agent=name), **extra}
    if key is not None:
        body["registration"] = wire.registration(name, key)
    return post_report(url, body)


# -- operators: API keys and roles ---------------------------------------------------------------------


def test_operator_endpoints_need_an_api_key(open_station: StationServer) -> None:
    url = open_station.url
    for method, path, body in (("GET", "/api/agents", None), ("POST", "/api/commands", {"command": "RTL"})):
        r = httpx.request(method, url + path, json=body)
        assert r.status_code == 401 and "API key" in r.json()["detail"], r.text
        assert r.headers["www-authenticate"] == "Bearer"
        r = httpx.request(method, url + path, json=body, headers={"Authorization": "Bearer antk_guessed"})
        assert r.status_code == 401 and "unknown API key" in r.json()["detail"]
    reader = {"Authorization": f"Bearer {READER_KEY}"}
    assert httpx.get(f"{url}/api/agents", headers=reader).status_code == 200
    r = httpx.post(f"{url}/api/commands", json={"command": "RTL"}, headers=reader)
    assert r.status_code == 403 and "read-only" in r.json()["detail"]
    assert httpx.post(f"{url}/api/commands", json={"command": "RTL"}, headers=AUTH).status_code == 200


def test_a_station_without_api_keys_answers_401_to_everyone(db_path: str) -> None:
    with StationServer(StationSettings(db_path=db_path)) as srv:
        assert httpx.get(f"{srv.url}/api/agents").status_code == 401
        assert httpx.get(f"{srv.url}/api/agents", headers=AUTH).status_code == 401
        assert register(srv.url, "uav1", key=None).status_code == 200  # agents still report


# -- tokens are secrets --------------------------------------------------------------------------------


def test_tokens_are_never_listed_and_only_their_hash_is_stored(db_path: str) -> None:
    with StationServer(settings_for(db_path)) as srv:
        tokens = [register(srv.url, f"uav{i}", key=None).json()["token"] for i in range(3)]
        listing = httpx.get(f"{srv.url}/api/agents", headers=AUTH)
        queued = httpx.post(f"{srv.url}/api/commands", json={"command": "RTL"}, headers=AUTH)
        for tok in tokens:
            assert tok not in listing.text and tok not in queued.text
        assert all(set(a) >= {"id", "name"} and "token" not in a for a in listing.json())
    raw = b"".join(
        p.read_bytes() for p in Path(db_path).parent.iterdir() if p.name.startswith("station.sqlite")
    )
    with sqlite3.connect(db_path) as conn:
        stored = dict(conn.execute("SELECT name, token_hash FROM agents").fetchall())
    for i, tok in enumerate(tokens):
        assert tok.encode() not in raw, "a token in clear in the database file"
        assert stored[f"uav{i}"] == sha256_hex(tok)


def test_a_token_reports_only_for_its_own_name(open_station: StationServer) -> None:
    token = register(open_station.url, "uav1", key=None).json()["token"]
    register(open_station.url, "uav2", key=None)
    r = post_report(open_station.url, {"token": token, "telemetry": tel(*ORIGIN, agent="uav2")})
    assert r.status_code == 409 and "uav1" in r.json()["detail"]


# -- registration proves the swarm key -------------------------------------------------------------------


def test_registration_needs_a_valid_fresh_unused_proof(keyed_station: StationServer) -> None:
    url = keyed_station.url
    r = register(url, "uav1", key=None)
    assert r.status_code == 401 and "swarm key" in r.json()["detail"]
    r = register(url, "uav1", key=generate_key())  # another swarm's key
    assert r.status_code == 401 and "does not match" in r.json()["detail"]
    old = int((time.time() - 600) * 1e6)
    nonce = "n" * 20
    stale = {"utime": old, "nonce": nonce, "mac": registration_mac(REG_KEY, "uav1", old, nonce)}
    r = post_report(url, {"agent": "uav1", "registration": stale})
    assert r.status_code == 401 and "window" in r.json()["detail"]
    proof = wire.registration("uav1", SWARM_KEY)
    r = post_report(url, {"agent": "uav1", "registration": proof})
    assert r.status_code == 200, r.text
    # The proof is for "uav1" only, and only once.
    assert post_report(url, {"agent": "uav2", "registration": proof}).status_code == 401
    r = post_report(url, {"agent": "uav1", "registration": proof})
    assert r.status_code == 401 and "replayed" in r.json()["detail"]
    assert [a["name"] for a in httpx.get(f"{url}/api/agents", headers=AUTH).json()] == ["uav1"]


def test_a_registered_name_cannot_be_squatted(open_station: StationServer) -> None:
    url = open_station.url
    first = register(url, "uav1", key=None)
    assert first.status_code == 200
    again = register(url, "uav1", key=None)
    assert again.status_code == 409 and "registered" in again.json()["detail"]
    assert post_report(url, {"token": first.json()["token"], "mc_state": "STANDBY"}).status_code == 200
    assert len(httpx.get(f"{url}/api/agents", headers=AUTH).json()) == 1


def test_a_proven_agent_takes_its_name_back_and_the_old_token_dies(keyed_station: StationServer) -> None:
    url = keyed_station.url
    old = register(url, "uav1").json()["token"]
    (before,) = httpx.get(f"{url}/api/agents", headers=AUTH).json()
    client = StationClient(url, OPERATOR_KEY, swarm_key=SWARM_KEY)
    client.command("TAKEOFF", target="uav1")
    new = register(url, "uav1")  # a restarted agent that lost its token proves the key again
    assert new.status_code == 200 and new.json()["token"] != old
    assert new.json()["operator_cmd"]["command"] == "TAKEOFF", "the queued command waited for it"
    (after,) = httpx.get(f"{url}/api/agents", headers=AUTH).json()
    assert after["id"] == before["id"]
    r = post_report(url, {"token": old})
    assert r.status_code == 401 and "unknown token" in r.json()["detail"]
    client.close()


def test_unsigned_commands_are_refused_when_the_agents_hold_a_key(keyed_station: StationServer) -> None:
    register(keyed_station.url, "uav1")
    r = httpx.post(f"{keyed_station.url}/api/commands", json={"command": "LAND"}, headers=AUTH)
    assert r.status_code == 422 and "sign" in r.json()["detail"]


# -- rate limits -----------------------------------------------------------------------------------------


def test_registrations_per_address_are_rate_limited(db_path: str) -> None:
    limits = RateLimits(registrations_per_minute=6.0, registration_burst=5)
    with StationServer(settings_for(db_path, rate_limits=limits)) as srv:
        codes = [register(srv.url, f"bot{i}", key=None) for i in range(8)]
        assert [r.status_code for r in codes] == [200] * 5 + [429] * 3
        assert int(codes[-1].headers["retry-after"]) >= 1
        assert "registrations" in codes[-1].json()["detail"]
        assert len(httpx.get(f"{srv.url}/api/agents", headers=AUTH).json()) == 5


def test_reports_per_agent_are_rate_limited(db_path: str) -> None:
    limits = RateLimits(reports_per_second=1.0, report_burst=3)
    with StationServer(settings_for(db_path, rate_limits=limits)) as srv:
        token = register(srv.url, "uav1", key=None).json()["token"]
        codes = [post_report(srv.url, {"token": token}).status_code for _ in range(6)]
        assert codes[:3] == [200] * 3 and codes[-1] == 429
        other = register(srv.url, "uav2", key=None).json()["token"]
        assert post_report(srv.url, {"token": other}).status_code == 200, "limits are per agent"


def test_requests_per_address_are_rate_limited(db_path: str) -> None:
    # one refill in 20 s: six requests on a loaded machine took over 2 s, and 1/s refilled the bucket
    limits = RateLimits(address_reports_per_second=0.05, address_burst=4)
    with StationServer(settings_for(db_path, rate_limits=limits)) as srv:
        codes = [httpx.get(f"{srv.url}/api/station").status_code for _ in range(6)]
        assert codes[:4] == [200] * 4 and codes[-1] == 429


# -- signed commands travel untouched --------------------------------------------------------------------


def test_a_signed_command_is_forwarded_field_for_field(keyed_station: StationServer) -> None:
    url = keyed_station.url
    token = register(url, "uav1").json()["token"]
    with StationClient(url, OPERATOR_KEY, swarm_key=SWARM_KEY, sender="console") as c:
        queued = c.command("TAKEOFF", target="uav1", altitude=12.5)
        c.direction(-90.0, 2.0)  # every agent
    reply = post_report(url, {"token": token}).json()
    op, dc = reply["operator_cmd"], reply["direction_cmd"]
    assert op == queued["queued"][0]["operator_cmd"]
    assert op["sender"] == "console" and op["target"] == "uav1" and op["altitude"] == 12.5
    assert dc["azimuth"] == 270.0 and dc["target"] == ""
    parsed = wire.parse_reply(httpx.Response(200, json=reply).content)
    msg = wire.operator_cmd(parsed, "uav1")
    assert msg is not None and verify(msg, SWARM_KEY, 5.0) is None, "the rebuilt message carries a valid MAC"
    d = wire.direction_cmd(parsed, "uav1")
    assert d is not None and verify(d, SWARM_KEY, 5.0) is None


def test_a_signed_command_for_an_unknown_agent_is_404(keyed_station: StationServer) -> None:
    with (
        StationClient(keyed_station.url, OPERATOR_KEY, swarm_key=SWARM_KEY) as c,
        pytest.raises(StationClientError) as err,
    ):
        c.command("LAND", target="nobody")
    assert err.value.status == 404


#: What an operator signs besides the command itself (the MAC is well-formed, not checked here).
SIGNED: dict[str, Any] = {"target": "", "utime": 1, "sender": "op", "seq": 1, "mac": "ab" * 32}


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("altitude", 1e6, "altitude"),
        ("mac", "00" * 31, "mac"),
        ("target", "a/b", "target"),
        ("seq", 0, "seq"),
        ("sender", "", "sender"),
    ],
)
def test_bad_signed_commands_get_422(open_station: StationServer, field: str, value: Any, words: str) -> None:
    body = {**SIGNED, "command": "TAKEOFF", "altitude": 0.0, field: value}
    r = httpx.post(f"{open_station.url}/api/commands", json={"operator_cmd": body}, headers=AUTH)
    assert r.status_code == 422 and words in r.json()["detail"], r.text


def test_signed_direction_must_not_need_wrapping(open_station: StationServer) -> None:
    body = {**SIGNED, "azimuth": 360.0, "speed": 1.0}
    r = httpx.post(f"{open_station.url}/api/commands", json={"direction_cmd": body}, headers=AUTH)
    assert r.status_code == 422 and "azimuth" in r.json()["detail"]


# -- the station's config file and keys ------------------------------------------------------------------


def test_station_file_round_trip(tmp_path: Path) -> None:
    cfg = tmp_path / "station.toml"
    cfg.write_text(
        '[station]\nhost = "127.0.0.1"\nport = 0\ndb = "s.sqlite"\n'
        f'registration_key = "{REG_KEY}"\n[rate_limits]\nregistration_burst = 7\n'
        f'[[api_keys]]\nname = "a"\nrole = "read-only"\nsha256 = "{sha256_hex(READER_KEY)}"\n'
    )
    f = load_station_file(cfg)
    assert f.settings.db_path == str(tmp_path / "s.sqlite") and f.settings.registration_key == REG_KEY
    assert f.settings.rate_limits.registration_burst == 7 and f.settings.api_keys[0].role == "read-only"
    cfg.write_text('[[api_keys]]\nname = "a"\nrole = "admin"\nsha256 = "00"\n')
    with pytest.raises(ConfigError, match=r"api_keys\[0\]\.role"):
        load_station_file(cfg)
    cfg.write_text(f'[[api_keys]]\nname = "a"\nrole = "operator"\nsha256 = "{OPERATOR_KEY}"\n')
    with pytest.raises(ConfigError, match="64 hex digits"):
        load_station_file(cfg)


def test_station_key_cli(tmp_path: Path) -> None:
    keyfile = tmp_path / "swarm.key"
    keyfile.write_text(SWARM_KEY + "\n")
    out = run_antalate("station-key", "registration", "--swarm-key-file", str(keyfile), check=True).stdout
    assert f'registration_key = "{REG_KEY}"' in out and SWARM_KEY not in out
    out = run_antalate("station-key", "api", "--name", "ci", "--role", "read-only", check=True).stdout
    key = next(w for w in out.split() if w.startswith("antk_"))
    assert f'sha256 = "{sha256_hex(key)}"' in out and 'role = "read-only"' in out
    cfg = tmp_path / "station.toml"
    cfg.write_text(out[out.index("[[api_keys]]") :])
    assert load_station_file(cfg).settings.api_keys[0].sha256 == sha256_hex(key)


def test_version_1_database_is_retired_not_trusted(db_path: str) -> None:
    with sqlite3.connect(db_path) as conn:
        conn.executescript(
            "CREATE TABLE agents (token TEXT PRIMARY KEY, name TEXT NOT NULL, first_seen REAL NOT NULL, "
            "last_seen REAL, mc_state TEXT, hlc_state TEXT, telemetry TEXT);"
            "CREATE TABLE reports (id INTEGER PRIMARY KEY, token TEXT NOT NULL, t REAL NOT NULL);"
            "CREATE TABLE commands (seq INTEGER PRIMARY KEY AUTOINCREMENT, t REAL, target TEXT, kind TEXT, body TEXT);"
            "CREATE TABLE deliveries (seq INTEGER, token TEXT, state TEXT, t_done REAL);"
            "INSERT INTO agents VALUES ('leakedtoken', 'uav1', 1.0, 2.0, NULL, NULL, NULL);"
            "PRAGMA user_version=1;"
        )
    with StationServer(settings_for(db_path)) as srv:
        assert httpx.get(f"{srv.url}/api/agents", headers=AUTH).json() == []
        assert post_report(srv.url, {"token": "leakedtoken"}).status_code == 401
        assert register(srv.url, "uav1", key=None).status_code == 200
    with sqlite3.connect(db_path) as conn:
        assert conn.execute("SELECT name FROM agents_v1").fetchall() == [("uav1",)]
        assert conn.execute("PRAGMA user_version").fetchone()[0] == 2


def test_openapi_declares_the_bearer_scheme(open_station: StationServer) -> None:
    doc = httpx.get(f"{open_station.url}/openapi.json").json()
    assert doc["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    assert doc["paths"]["/api/commands"]["post"]["security"] == [{"HTTPBearer": []}]
    assert "security" not in doc["paths"]["/api/report"]["post"], "agents use their token, not an API key"
    assert set(API_KEYS[0].model_dump()) == {"name", "role", "sha256"}


def test_station_cli_refuses_a_bad_config_or_tls_pair_before_listening(tmp_path: Path) -> None:
    station = ("station", "--port", "0", "--db", ":memory:")
    cfg = tmp_path / "station.toml"
    cfg.write_text('[station]\nregistration_key = "not hex"\n')
    r = run_antalate(*station, "--config", str(cfg))
    assert r.returncode == 2 and "station.registration_key" in r.stderr and "Traceback" not in r.stderr
    r = run_antalate(*station, "--tls-cert", str(cfg))
    assert r.returncode == 2 and "--tls-key" in r.stderr
    r = run_antalate(*station, "--tls-cert", str(cfg), "--tls-key", str(cfg))
    assert r.returncode == 2 and "cannot use TLS certificate" in r.stderr and "Traceback" not in r.stderr
