"""The peer table (antalate_lcm.wire.peers): frames, ages, staleness, centroid, and what it refuses."""

from __future__ import annotations

import math

import pytest

from antalate_lcm.base import geo
from antalate_lcm.msgs import mc_state_t, telemetry_t
from antalate_lcm.wire.peers import Peer, PeerTable

ORIGIN = (32.7767, 35.0231)


def telemetry(
    north: float = 0.0,
    east: float = 0.0,
    *,
    alt: float = 10.0,
    utime: int = 1,
    heading: float = 0.0,
    vn: float = 0.0,
    ve: float = 0.0,
    vd: float = 0.0,
) -> telemetry_t:
    msg = telemetry_t()
    msg.lat, msg.lon = geo.offset(*ORIGIN, north, east)
    msg.alt = alt
    msg.heading = heading
    msg.vn, msg.ve, msg.vd = vn, ve, vd
    msg.armed = msg.in_air = True
    msg.mode = "SIM"
    msg.header.utime = utime
    return msg


def table(**kw: float) -> PeerTable:
    return PeerTable("me", origin=ORIGIN, **kw)  # type: ignore[arg-type]


def test_positions_are_in_the_origins_local_frame() -> None:
    t = table()
    assert t.update_telemetry(
        "b", telemetry(30.0, -40.0, alt=12.5, vn=1.0, ve=2.0, vd=-0.5, heading=370), 5.0
    )
    p = t.get("b")
    assert p is not None
    # the flat frame is within 1 cm of the geodesic at 50 m
    assert (p.north, p.east) == pytest.approx((30.0, -40.0), abs=0.01)
    assert p.up == p.alt == 12.5
    assert p.position == pytest.approx((30.0, -40.0, 12.5), abs=0.01)
    assert p.velocity == (1.0, 2.0, 0.5)  # up = -down
    assert p.speed == pytest.approx(math.sqrt(5.0))
    assert p.heading == 10.0  # wrapped into [0, 360)
    assert p.lat == pytest.approx(geo.offset(*ORIGIN, 30.0, -40.0)[0])
    assert p.age(7.5) == 2.5


def test_without_an_origin_the_first_position_fed_is_the_origin() -> None:
    t = PeerTable("me")
    assert t.origin is None
    first = telemetry(100.0, 100.0)
    t.update_telemetry("me", first, 0.0)
    assert t.origin == (first.lat, first.lon)
    me = t.me
    assert me is not None and (me.north, me.east) == (0.0, 0.0)
    t.update_telemetry("b", telemetry(103.0, 104.0), 0.0)
    b = t.get("b")
    assert b is not None and t.relative(b) == pytest.approx((3.0, 4.0, 0.0), abs=0.01)


def test_the_own_agent_is_me_never_a_peer() -> None:
    t = table()
    t.update_telemetry("me", telemetry(1.0, 1.0), 0.0)
    t.update_telemetry("b", telemetry(2.0, 2.0), 0.0)
    assert t.me is not None and t.me.agent == "me"
    assert [p.agent for p in t.peers(0.0)] == ["b"]
    assert "me" not in t and "b" in t and len(t) == 1


def test_relative_needs_the_own_position() -> None:
    t = table()
    t.update_telemetry("b", telemetry(5.0, 0.0), 0.0)
    b = t.get("b")
    assert b is not None and t.relative(b) is None
    t.update_telemetry("me", telemetry(1.0, 1.0, alt=8.0), 0.0)
    assert t.relative(b) == pytest.approx((4.0, -1.0, 2.0), abs=0.01)


def test_stale_peers_are_left_out_and_forgotten_later() -> None:
    t = table(stale_after=1.0, forget_after=5.0)
    t.update_telemetry("a", telemetry(0.0, 0.0), 0.0)
    t.update_telemetry("b", telemetry(10.0, 0.0), 0.8)
    assert [p.agent for p in t.peers(1.5)] == ["b"]
    assert [p.agent for p in t.stale(1.5)] == ["a"]
    assert [p.agent for p in t.peers(1.5, max_age=2.0)] == ["a", "b"]
    assert [p.agent for p in t] == ["a", "b"]  # iteration includes stale peers
    assert t.forget(5.5) == ["a"]
    assert t.get("a") is None and len(t) == 1
    assert t.forget(5.5) == []


def test_centroid_of_fresh_peers_with_or_without_self() -> None:
    t = table()
    assert t.centroid(0.0) is None
    t.update_telemetry("me", telemetry(0.0, 0.0, alt=0.0), 0.0)
    assert t.centroid(0.0) is None
    assert t.centroid(0.0, include_self=True) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    for name, (n, e) in {"a": (10.0, 0.0), "b": (0.0, 10.0), "c": (-10.0, 20.0)}.items():
        t.update_telemetry(name, telemetry(n, e, alt=6.0), 0.0)
    assert t.centroid(0.5) == pytest.approx((0.0, 10.0, 6.0), abs=0.01)
    assert t.centroid(0.5, include_self=True) == pytest.approx((0.0, 7.5, 4.5), abs=0.01)
    t.update_telemetry("a", telemetry(10.0, 0.0, alt=6.0, utime=2), 2.0)
    assert t.centroid(2.5) == pytest.approx((10.0, 0.0, 6.0), abs=0.01)  # b and c are stale


def test_mc_state_by_value_or_name_before_or_after_telemetry() -> None:
    t = table()
    assert t.update_state("a", mc_state_t.MISSION, 0.0)
    t.update_telemetry("a", telemetry(), 0.0)
    a = t.get("a")
    assert a is not None and a.mc_state == "MISSION"
    assert t.update_state("a", "RTL", 0.0)
    t.update_telemetry("a", telemetry(utime=2), 0.1)  # new telemetry keeps the state
    a = t.get("a")
    assert a is not None and a.mc_state == "RTL"
    t.update_telemetry("me", telemetry(), 0.0)
    assert t.update_state("me", mc_state_t.LAND, 0.0)
    assert t.me is not None and t.me.mc_state == "LAND"
    t.update_telemetry("b", telemetry(), 0.0)
    b = t.get("b")
    assert b is not None and b.mc_state is None  # nothing heard yet


def test_an_undefined_mc_state_is_refused() -> None:
    t = table()
    t.update_telemetry("a", telemetry(), 0.0)
    assert not t.update_state("a", 99, 0.0)
    assert not t.update_state("a", "FLYING", 0.0)
    a = t.get("a")
    assert a is not None and a.mc_state is None


def test_a_state_does_not_refresh_the_age() -> None:
    t = table(stale_after=1.0)
    t.update_telemetry("a", telemetry(), 0.0)
    t.update_state("a", "MISSION", 3.0)
    a = t.get("a")
    assert a is not None and a.received == 0.0 and t.peers(3.0) == []


@pytest.mark.parametrize("field", ["lat", "lon", "alt", "heading", "vn", "ve", "vd"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_telemetry_is_refused(field: str, bad: float) -> None:
    t = table()
    msg = telemetry()
    setattr(msg, field, bad)
    assert not t.update_telemetry("a", msg, 0.0)
    assert t.get("a") is None and t.rejected == 1


def test_a_latitude_off_the_earth_is_refused() -> None:
    t = table()
    msg = telemetry()
    msg.lat = 91.0
    assert not t.update_telemetry("a", msg, 0.0)


def test_a_repeated_or_older_message_is_refused() -> None:
    """The same datagram heard twice (two buses, a replay) or late must not move the record back."""
    t = table()
    assert t.update_telemetry("a", telemetry(1.0, 0.0, utime=10), 0.0)
    assert not t.update_telemetry("a", telemetry(1.0, 0.0, utime=10), 0.1)
    assert not t.update_telemetry("a", telemetry(50.0, 0.0, utime=9), 0.1)
    a = t.get("a")
    assert a is not None and a.north == pytest.approx(1.0, abs=0.01) and a.received == 0.0
    assert t.rejected == 2
    assert t.update_telemetry("me", telemetry(utime=10), 0.0)
    assert not t.update_telemetry("me", telemetry(utime=10), 0.0)


def test_the_table_is_bounded() -> None:
    t = table(forget_after=5.0)
    t.max_peers = 3
    for i in range(3):
        assert t.update_telemetry(f"p{i}", telemetry(), 0.0)
    assert not t.update_telemetry("p3", telemetry(), 1.0)  # full, nobody old enough to forget
    assert t.update_telemetry("p0", telemetry(utime=2), 1.0)  # a known peer still updates
    assert t.update_telemetry("me", telemetry(), 1.0)  # and this agent is never counted
    assert t.update_telemetry("p3", telemetry(), 5.5)  # p1, p2 forgotten to make room
    assert sorted(p.agent for p in t) == ["p0", "p3"]
    for i in range(3):
        t.update_state(f"x{i}", "MISSION", 0.0)
    assert not t.update_state("x3", "MISSION", 0.0)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"stale_after": 0.0}, "stale_after"),
        ({"stale_after": math.nan}, "stale_after"),
        ({"stale_after": 2.0, "forget_after": 1.0}, "forget_after"),
        ({"max_peers": 0}, "max_peers"),
        ({"origin": (math.nan, 0.0)}, "origin"),
        ({"origin": (95.0, 0.0)}, "origin"),
    ],
)
def test_bad_parameters_are_refused(kw: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        PeerTable("me", **kw)  # type: ignore[arg-type]


def test_a_peer_record_is_immutable() -> None:
    t = table()
    t.update_telemetry("a", telemetry(), 0.0)
    a = t.get("a")
    assert isinstance(a, Peer)
    with pytest.raises(AttributeError):
        a.north = 3.0  # type: ignore[misc]
