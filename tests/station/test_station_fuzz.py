"""A bounded HTTP fuzz of the real station (uvicorn on 127.0.0.1, a SQLite file) from its own OpenAPI.

schemathesis generates requests for every operation, valid and invalid against the schema, with
and without an operator's API key; hypothesis adds raw bytes and JSON of the wrong shapes for the
report endpoint. A few thousand requests in all. Whatever arrives, the station must answer 4xx or
200 (never 5xx), keep serving, and keep its database intact with the agents it had.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

schemathesis = pytest.importorskip(
    "schemathesis", reason="the fuzz needs schemathesis (pip install -e '.[dev]')"
)
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from antalate_lcm.station import StationServer, StationSettings  # noqa: E402
from antalate_lcm.station._settings import RateLimits  # noqa: E402
from antalate_lcm.station.openapi import document  # noqa: E402
from tests.station.test_station import API_KEYS, AUTH, ORIGIN, tel  # noqa: E402

EXAMPLES = 300  # per operation and mode (and for the raw bodies): about 2,100 requests in all
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)


@pytest.fixture(scope="module")
def station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[StationServer, list[str]]]:
    db = tmp_path_factory.mktemp("fuzz") / "station.sqlite"
    limits = RateLimits(
        registrations_per_minute=None, reports_per_second=None, address_reports_per_second=None
    )
    with StationServer(StationSettings(db_path=str(db), api_keys=API_KEYS, rate_limits=limits)) as srv:
        tokens = [
            httpx.post(f"{srv.url}/api/report", json={"agent": f"keep{i}", "telemetry": tel(*ORIGIN)}).json()[
                "token"
            ]
            for i in range(3)
        ]
        yield srv, tokens


def _check(response: Any, what: str) -> None:
    assert response.status_code < 500, f"{what}: {response.status_code} {response.text[:300]}"


SENT: dict[str, int] = {}  # requests per test, checked at the end: the fuzz must really have run
# Negative cases need something to break: a body, parameters or a credential.
OPERATIONS = [
    (path, method, mode)
    for path, ops in document()["paths"].items()
    for method, op in ops.items()
    for mode in ("positive", "negative")
    if mode == "positive" or "requestBody" in op or op.get("parameters") or op.get("security")
]


@pytest.mark.parametrize(("path", "method", "mode"), OPERATIONS)
def test_schema_fuzz_never_gets_a_5xx(
    station: tuple[StationServer, list[str]], path: str, method: str, mode: str
) -> None:
    srv, _ = station
    schema = schemathesis.openapi.from_dict(document())
    generation = (
        schemathesis.GenerationMode.POSITIVE if mode == "positive" else schemathesis.GenerationMode.NEGATIVE
    )
    strategy = schema[path][method.upper()].as_strategy(generation_mode=generation)
    key = f"{method.upper()} {path} {mode}"
    SENT[key] = 0

    @FUZZ
    @given(case=strategy, authorised=st.booleans())
    def run(case: Any, authorised: bool) -> None:
        SENT[key] += 1
        response = case.call(base_url=srv.url, headers=AUTH if authorised else None, timeout=10)
        _check(response, key)

    run()
    assert SENT[key] >= 1


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner, max_size=4),
    max_leaves=12,
)
_REPORT_KEYS = ["token", "agent", "registration", "mc_state", "hlc_state", "telemetry", "feedback"]


def test_raw_report_bodies_never_get_a_5xx(station: tuple[StationServer, list[str]]) -> None:
    srv, tokens = station
    with httpx.Client(base_url=srv.url, timeout=10) as client:

        @FUZZ
        @given(
            body=st.binary(max_size=300)
            | st.builds(
                lambda d: json.dumps(d).encode(), st.dictionaries(st.sampled_from(_REPORT_KEYS), _JSON)
            )
            | st.builds(lambda d: json.dumps(d).encode(), _JSON),
            content_type=st.sampled_from([None, "application/json", "text/plain", "application/x+json; q=1"]),
        )
        def run(body: bytes, content_type: str | None) -> None:
            SENT["raw"] = SENT.get("raw", 0) + 1
            headers = {"content-type": content_type} if content_type else {}
            _check(client.post("/api/report", content=body, headers=headers), "POST /api/report")

        run()
        # Still serving, the agents it had still report with their tokens.
        assert client.get("/api/station").status_code == 200
        for tok in tokens:
            assert client.post("/api/report", json={"token": tok}).status_code == 200


def test_after_the_fuzz_the_database_is_intact(station: tuple[StationServer, list[str]]) -> None:
    srv, tokens = station
    print(f"fuzz: {sum(SENT.values())} requests: {SENT}")
    assert sum(SENT.values()) >= 2000, SENT
    names = {a["name"] for a in httpx.get(f"{srv.url}/api/agents", headers=AUTH).json()}
    assert {"keep0", "keep1", "keep2"} <= names
    srv.stop()
    path = Path(srv.settings.db_path)
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        assert conn.execute("PRAGMA foreign_key_check").fetchall() == []
        kept = {n for (n,) in conn.execute("SELECT name FROM agents WHERE name LIKE 'keep%'")}
    assert kept == {"keep0", "keep1", "keep2"}
