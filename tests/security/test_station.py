"""Issue 13, attack 2: the station is open. Raw HTTP from another address, with no credential, a
read-only key, guessed tokens, other agents' names, unproven or replayed registrations, a flood; and
with a stolen operator key, commands the operator never signed.

alpha (on the ground, keyed, OSC reporting) is the target throughout: after every attack it must
still be on the ground in STANDBY, still reporting to the station under its own token, with its
genuine position.
"""

from __future__ import annotations

import json
import math
import secrets
import shutil
import sqlite3
import time
from typing import Any

import pytest

from antalate_lcm.base.geo import offset
from antalate_lcm.msgs import operator_cmd_t
from antalate_lcm.station._auth import registration_key, registration_mac
from tests.harness.polling import wait_for
from tests.security.harness import (
    HOME,
    OPERATOR,
    STATION_PORT,
    SWARM_KEY,
    AgentRun,
    Baseline,
    PeerClient,
    Swarm,
    assert_unmoved,
    baseline,
)

pytestmark = pytest.mark.netns

FAR = offset(HOME[0], HOME[1], 5000.0, 5000.0)  # where the attacker says alpha is


def agents(swarm: Swarm, operator: PeerClient) -> list[dict[str, Any]]:
    r = operator.http1("GET", "/api/agents", headers=swarm.auth("read-only"))
    assert r["status"] == 200, r
    return list(r["body"])


def station_view(swarm: Swarm, operator: PeerClient, name: str) -> dict[str, Any]:
    rows = [a for a in agents(swarm, operator) if a["name"] == name]
    assert len(rows) == 1, f"{len(rows)} agents named {name!r} at the station: {rows}"
    return rows[0]


@pytest.fixture
def alpha(swarm: Swarm, operator: PeerClient) -> AgentRun:
    """alpha, registered and reporting (fresh) to the station, on the ground in STANDBY."""
    run = swarm.agents["alpha"]
    assert run.mc_state() == "STANDBY"
    t = time.time()
    fresh = wait_for(
        lambda: (lambda a: a if (a.get("last_seen") or 0) > t else None)(
            station_view(swarm, operator, "alpha")
        ),
        20.0,
        0.2,
    )
    assert fresh, "alpha does not report to the station"
    return run


def still_reporting(swarm: Swarm, operator: PeerClient, run: AgentRun, before: Baseline) -> dict[str, Any]:
    """The target is untouched: unmoved, and still reporting under its own name and token."""
    assert_unmoved(run, before)
    t = time.time()
    row = wait_for(
        lambda: (lambda a: a if (a.get("last_seen") or 0) > t else None)(
            station_view(swarm, operator, run.name)
        ),
        15.0,
        0.2,
    )
    assert row, f"{run.name} stopped reporting to the station: {station_view(swarm, operator, run.name)}"
    assert "token hijack" not in swarm.station_text()
    return row


def count(swarm: Swarm, operator: PeerClient) -> int:
    return len(agents(swarm, operator))


TAKEOFF_ALPHA = {"command": "TAKEOFF", "target": "alpha", "altitude": 2.1}


@pytest.mark.attack("POST /api/commands and GET /api/agents with no credential (or a made-up one)")
def test_no_credential(swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun) -> None:
    before = baseline(alpha)
    for headers in (
        None,
        {"Authorization": "Bearer antk_" + secrets.token_urlsafe(32)},
        {"Authorization": "Basic YWRtaW46YWRtaW4="},
        {"X-API-Key": swarm.api_keys["operator"][:-1]},
    ):
        for body in (TAKEOFF_ALPHA, {"command": "TAKEOFF"}, {"direction": {"azimuth": 0, "speed": 3}}):
            r = attacker.http1("POST", "/api/commands", body, headers=headers)
            assert r["status"] == 401, r
        assert attacker.http1("GET", "/api/agents", headers=headers)["status"] == 401
    still_reporting(swarm, operator, alpha, before)
    assert station_view(swarm, operator, "alpha")["pending_commands"] == 0


@pytest.mark.attack("POST /api/commands with a read-only API key")
def test_read_only_key_cannot_command(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    for body in (TAKEOFF_ALPHA, {"command": "TAKEOFF"}, {"direction": {"azimuth": 0, "speed": 3}}):
        r = attacker.http1("POST", "/api/commands", body, headers=swarm.auth("read-only"))
        assert r["status"] == 403, r
    still_reporting(swarm, operator, alpha, before)
    assert station_view(swarm, operator, "alpha")["pending_commands"] == 0


@pytest.mark.attack("GET /api/agents to harvest agents' tokens")
def test_tokens_are_never_listed(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    tokens = {name: (swarm.tmp / f"{name}.token").read_text().strip() for name in ("alpha", "delta")}
    assert all(len(t) >= 16 for t in tokens.values()), tokens
    r = attacker.http1("GET", "/api/agents", headers=swarm.auth("read-only"))
    assert r["status"] == 200
    listing = str(r["body"])
    for name, token in tokens.items():
        assert token not in listing, f"GET /api/agents lists {name}'s token"
    # Nor are they kept in the clear where a copied database would give them away.
    db = sqlite3.connect(f"file:{swarm.station_db}?mode=ro", uri=True)
    try:
        dump = "\n".join(db.iterdump())
    finally:
        db.close()
    for name, token in tokens.items():
        assert token not in dump, f"the station's database holds {name}'s token in the clear"


def report(
    token: str | None, name: str | None = "alpha", lat_lon: tuple[float, float] = FAR, **extra: Any
) -> dict[str, Any]:
    tel: dict[str, Any] = {
        "lat": lat_lon[0],
        "lon": lat_lon[1],
        "heading": 0.0,
        "alt": 50.0,
        "in_air": True,
        "armed": True,
    }
    if name is not None:
        tel["agent"] = name
    return {"token": token, "mc_state": "MISSION", "hlc_state": "AIRBORNE", "telemetry": tel, **extra}


@pytest.mark.attack("guessed tokens poll away the commands queued for a real agent")
def test_guessed_tokens_poll_away_nothing(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    public_id = station_view(swarm, operator, "alpha")["id"]
    mark = operator.mark()
    seqs = []
    for _ in range(10):  # LAND in STANDBY moves nothing: the MC rejects it, but it must get there
        seq = swarm.next_seq()
        seqs.append(seq)
        cmd = _signed_command(swarm, "LAND", "alpha", seq)
        r = operator.http1("POST", "/api/commands", {"operator_cmd": cmd}, headers=swarm.auth("operator"))
        assert r["status"] == 200, r
        guesses = [
            report(g)
            for g in (
                public_id,
                "alpha",
                secrets.token_urlsafe(24),
                secrets.token_urlsafe(12),
                "",
                "null",
                public_id.upper(),
            )
        ]
        for reply in attacker.http("POST", "/api/report", bodies=guesses):
            assert reply["status"] in (401, 422, 429), reply
            assert "operator_cmd" not in str(reply["body"]), f"the attacker polled a command away: {reply}"

    # Every command reached alpha: its OSC published all ten on the LAN, signed.
    def delivered() -> list[int]:
        return sorted(
            {
                m["header"]["seq"]
                for m in operator.history("alpha/OPERATOR_CMD", "operator_cmd_t", since=mark, genuine=True)
            }
        )

    assert wait_for(lambda: delivered() == sorted(seqs), 20.0, 0.2), (
        f"delivered {delivered()} of {sorted(seqs)}"
    )
    row = still_reporting(swarm, operator, alpha, before)
    assert row["pending_commands"] == 0


def _signed_command(
    swarm: Swarm, command: str, target: str, seq: int, altitude: float = 0.0
) -> dict[str, Any]:
    """What the operator's client POSTs: an operator_cmd_t signed with the swarm key, field by field."""
    from antalate_lcm.station.client import build_operator_cmd, operator_cmd_wire

    msg = build_operator_cmd(
        command,
        target=target,
        altitude=altitude,
        sender=OPERATOR,
        seq=seq,
        utime=time.time_ns() // 1000,
        key=SWARM_KEY,
    )
    return operator_cmd_wire(msg)


@pytest.mark.attack("false position reported for a real agent (its name, guessed tokens, no token)")
def test_false_position_for_a_real_agent(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    public_id = station_view(swarm, operator, "alpha")["id"]
    bodies = [
        report(None),
        report(None, agent="alpha"),
        report(public_id),
        report(secrets.token_urlsafe(24)),
        report(None, name=None, agent="alpha"),
    ]
    for reply in attacker.http("POST", "/api/report", bodies=bodies * 4):
        assert reply["status"] in (401, 409, 429), reply
    row = still_reporting(swarm, operator, alpha, before)
    lat, lon = row["telemetry"]["lat"], row["telemetry"]["lon"]
    assert math.hypot(lat - HOME[0], lon - HOME[1]) < 1e-4, f"the station shows alpha at {lat}, {lon}"


def _proof(name: str, key: str = SWARM_KEY, age: float = 0.0) -> dict[str, Any]:
    utime = int((time.time() - age) * 1e6)
    nonce = secrets.token_urlsafe(16)
    return {
        "utime": utime,
        "nonce": nonce,
        "mac": registration_mac(registration_key(key), name, utime, nonce),
    }


@pytest.mark.attack("registration without a proof of the swarm key (none, another key, stale, forged)")
def test_registration_without_proof(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    n = count(swarm, operator)
    bodies = [
        report(None, "mallory", HOME),
        report(
            None, "mallory", HOME, agent="mallory", registration=_proof("mallory", key="not-the-swarm-key")
        ),
        report(None, "mallory", HOME, agent="mallory", registration=_proof("mallory", age=3600.0)),
        report(
            None,
            "mallory",
            HOME,
            agent="mallory",
            registration={**_proof("mallory"), "mac": secrets.token_hex(32)},
        ),
        report(None, "mallory", HOME, agent="mallory", registration=_proof("someone-else")),
    ]
    for reply in attacker.http("POST", "/api/report", bodies=bodies):
        assert reply["status"] == 401, reply
        assert (
            "token" not in reply["body"]
            or not isinstance(reply["body"], dict)
            or reply["body"].get("token") is None
        )
    assert count(swarm, operator) == n
    assert all(a["name"] != "mallory" for a in agents(swarm, operator))


@pytest.mark.attack("name squatting: taking a registered name, or replaying another agent's registration")
def test_name_squatting(swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun) -> None:
    before = baseline(alpha)
    # A genuine registration the attacker saw go by (plain HTTP on a LAN): "echo" registers once...
    echo = report(None, "echo", HOME, agent="echo", registration=_proof("echo"))
    first = operator.http1("POST", "/api/report", echo)
    assert first["status"] == 200, first
    n = count(swarm, operator)
    # ... and the attacker replays it to get a token for "echo", and claims alpha's name outright.
    replies = attacker.http(
        "POST",
        "/api/report",
        bodies=[
            echo,
            echo,
            report(None, "alpha", HOME),
            report(None, "alpha", HOME, agent="alpha"),
            report(None, "ALPHA", HOME),
        ],
    )
    assert replies[0]["status"] == 401 and replies[1]["status"] == 401, replies[:2]
    for reply in replies[2:]:
        assert reply["status"] in (401, 409), reply
    assert count(swarm, operator) == n
    # echo keeps its own token: it still reports under it.
    again = operator.http1("POST", "/api/report", report(first["body"]["token"], "echo", HOME))
    assert again["status"] == 200, again
    still_reporting(swarm, operator, alpha, before)


@pytest.mark.attack("registration flood (500 first contacts in a burst)")
def test_registration_flood(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    n = count(swarm, operator)
    bodies = [report(None, f"flood-{i}", HOME, agent=f"flood-{i}") for i in range(500)]
    # From an address of its own, so the other tests' budget of registrations is left alone.
    replies = attacker.http("POST", "/api/report", bodies=bodies, source="127.0.0.3")
    statuses = [r["status"] for r in replies]
    assert 429 in statuses, f"no rate limit: {sorted(set(statuses))}"
    assert set(statuses) <= {401, 429}, sorted(set(statuses))
    limited = next(r for r in replies if r["status"] == 429)
    assert limited["body"].get("detail"), limited
    assert count(swarm, operator) == n, "the flood registered agents"
    still_reporting(swarm, operator, alpha, before)


@pytest.mark.attack("stolen operator key: an unsigned TAKEOFF through the station")
def test_stolen_operator_key_unsigned_command(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    r = attacker.http1("POST", "/api/commands", TAKEOFF_ALPHA, headers=swarm.auth("operator"))
    # The station may refuse it, or queue it for the OSC to drop: either way alpha must not fly.
    assert r["status"] in (200, 403, 422), r
    still_reporting(swarm, operator, alpha, before)
    assert station_view(swarm, operator, "alpha")["pending_commands"] == 0


@pytest.mark.attack(
    "stolen operator key: a genuine signed command re-targeted (and re-stamped) to a real agent"
)
def test_stolen_operator_key_retargeted_signed_command(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    mark = attacker.mark()
    # The operator sends a signed TAKEOFF to zulu (no such agent) on the LAN; the attacker records it.
    operator.publish(
        "zulu/OPERATOR_CMD",
        "operator_cmd_t",
        sign=True,
        header={"agent": OPERATOR, "seq": swarm.next_seq()},
        command=operator_cmd_t.TAKEOFF,
        target="zulu",
        altitude=2.1,
    )
    seen = attacker.wait("zulu/OPERATOR_CMD", "operator_cmd_t", since=mark, timeout=5)
    assert seen is not None
    h = seen["header"]
    genuine = {
        "target": "zulu",
        "utime": h["utime"],
        "sender": h["agent"],
        "seq": h["seq"],
        "mac": h["mac"],
        "command": "TAKEOFF",
        "altitude": seen["altitude"],
    }
    forgeries = [
        {**genuine, "target": "alpha"},
        {**genuine, "target": ""},
        {**genuine, "target": "alpha", "utime": time.time_ns() // 1000},
        {**genuine, "target": "alpha", "seq": h["seq"] + 1},
    ]
    for cmd in forgeries:
        r = attacker.http1("POST", "/api/commands", {"operator_cmd": cmd}, headers=swarm.auth("operator"))
        assert r["status"] in (200, 403, 422), r
    still_reporting(swarm, operator, alpha, before)


@pytest.mark.attack("TAKEOFF altitude and direction azimuth/speed Infinity/NaN/1e999 through the station")
def test_non_finite_altitude_through_the_station(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    for alt in ("Infinity", "NaN", "1e999", "-Infinity"):
        # Python's json writes Infinity/NaN (not JSON); 1e999 is JSON that overflows a double.
        body = json.dumps({"command": "TAKEOFF", "target": "alpha", "altitude": 1.5}).replace("1.5", alt)
        r = attacker.http1(
            "POST",
            "/api/commands",
            content=body,
            headers={**swarm.auth("operator"), "Content-Type": "application/json"},
        )
        assert r["status"] == 422, r
        signed = _signed_command(swarm, "TAKEOFF", "alpha", swarm.next_seq())
        body = json.dumps({"operator_cmd": signed}).replace('"altitude": 0.0', f'"altitude": {alt}')
        assert alt in body
        r = attacker.http1(
            "POST",
            "/api/commands",
            content=body,
            headers={**swarm.auth("operator"), "Content-Type": "application/json"},
        )
        assert r["status"] == 422, r
    for az, speed in (
        ("Infinity", "1.0"),
        ("NaN", "1.0"),
        ("1e999", "1.0"),
        ("90.0", "Infinity"),
        ("90.0", "NaN"),
        ("90.0", "1e999"),
    ):
        body = '{"target": "alpha", "direction": {"azimuth": %s, "speed": %s}}' % (az, speed)  # noqa: UP031
        r = attacker.http1(
            "POST",
            "/api/commands",
            content=body,
            headers={**swarm.auth("operator"), "Content-Type": "application/json"},
        )
        assert r["status"] == 422, (body, r)
    still_reporting(swarm, operator, alpha, before)
    assert station_view(swarm, operator, "alpha")["pending_commands"] == 0


@pytest.mark.attack("stolen operator key: a signed command alpha already received, POSTed again (a replay)")
def test_stolen_operator_key_replays_a_delivered_command(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    before = baseline(alpha)
    mark = operator.mark()
    seq = swarm.next_seq()
    cmd = _signed_command(
        swarm, "LAND", "alpha", seq
    )  # LAND on the ground: rejected by the MC, moves nothing
    assert (
        operator.http1("POST", "/api/commands", {"operator_cmd": cmd}, headers=swarm.auth("operator"))[
            "status"
        ]
        == 200
    )

    def copies() -> int:
        return sum(
            m["header"]["seq"] == seq
            for m in operator.history("alpha/OPERATOR_CMD", "operator_cmd_t", since=mark, genuine=True)
        )

    assert wait_for(lambda: copies() >= 1, 15.0, 0.2), "the genuine command never reached alpha"
    delivered = copies()
    # The attacker saw it go by on the LAN (or in the station's database) and queues it again, and
    # once more re-stamped (which breaks the MAC).
    for body in (
        {"operator_cmd": cmd},
        {"operator_cmd": cmd},
        {"operator_cmd": {**cmd, "utime": time.time_ns() // 1000}},
    ):
        r = attacker.http1("POST", "/api/commands", body, headers=swarm.auth("operator"))
        assert r["status"] in (200, 403, 409, 422), r
    t = time.time()
    assert wait_for(
        lambda: (lambda a: a if (a.get("last_seen") or 0) > t + 1.0 else None)(
            station_view(swarm, operator, "alpha")
        ),
        15.0,
        0.2,
    ), "alpha stopped reporting"
    assert copies() == delivered, "alpha's OSC published the replayed command again"
    still_reporting(swarm, operator, alpha, before)


@pytest.mark.attack("tokens and registrations sniffed off the link between the OSCs and the station")
def test_sniffing_the_station_link_gives_nothing_away(
    swarm: Swarm, attacker: PeerClient, operator: PeerClient, alpha: AgentRun
) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: the suite's station cannot serve HTTPS")
    problem = attacker.sniff_start(STATION_PORT)
    if problem:
        pytest.skip(problem)
    t = time.time()
    # Every OSC reports at 5 Hz: wait for a few reports to have crossed the link while the attacker listened.
    assert wait_for(lambda: station_view(swarm, operator, "alpha")["last_seen"] > t + 1.5, 15.0, 0.2)
    captured = attacker.sniff_take()
    assert len(captured) > 1000, f"the sniffer saw only {len(captured)} bytes: it did not see the link"
    for name in ("alpha", "delta", "charlie"):
        token = (swarm.tmp / f"{name}.token").read_text().strip()
        assert token.encode() not in captured, f"{name}'s token crossed the link in the clear"
    for plain in (b'"token"', b'"telemetry"', b"Bearer ", b"POST /api/"):
        assert plain not in captured, f"{plain!r} crossed the link in the clear"
    # And the station does not answer in the clear either.
    plain_http = attacker.http1("GET", f"http://127.0.0.1:{STATION_PORT}/api/station")
    assert plain_http["status"] != 200, plain_http
