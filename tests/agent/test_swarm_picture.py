"""The per-process swarm picture: one table for every agent, a grid for the filter's queries."""

from __future__ import annotations

import math

import pytest

from antalate_lcm.agent.hlc.swarm_picture import SwarmPicture
from antalate_lcm.base.geo import offset
from antalate_lcm.msgs import telemetry_t

LAT0, LON0 = 32.7767, 35.0231


def tel(north: float, east: float, utime: int, alt: float = 10.0) -> telemetry_t:
    msg = telemetry_t()
    msg.lat, msg.lon = offset(LAT0, LON0, north, east)
    msg.alt = alt
    msg.in_air = True
    msg.header.utime = utime
    return msg


def picture() -> SwarmPicture:
    return SwarmPicture(cell=10.0, stale_after=1.0, forget_after=5.0, origin=(LAT0, LON0))


def test_near_returns_the_agents_of_the_neighbouring_cells_only() -> None:
    pic = picture()
    for i in range(10):
        assert pic.feed(f"a{i}", tel(i * 8.0, 0.0, 1), 0.0)
    near = {p.agent for p in pic.near("a0", 0.0, 0.0, 10.0)}
    assert near == {"a1", "a2"}  # cells -1..1: north up to 20 m (a1 at 8, a2 at 16)
    assert {p.agent for p in pic.near("a5", 40.0, 0.0, 10.0)} == {"a4", "a6", "a7"}  # cells 3..5: 30-60 m
    assert pic.fresh("a0") == 9 and pic.fresh("nobody") == 10 and len(pic) == 10
    got = pic.near("a0", 0.0, 0.0, 10.0)
    assert all(math.isclose(p.north, int(p.agent[1:]) * 8.0, abs_tol=0.01) for p in got)


def test_an_agent_that_moves_changes_cell() -> None:
    pic = picture()
    pic.feed("a", tel(0.0, 0.0, 1), 0.0)
    pic.feed("b", tel(100.0, 0.0, 1), 0.0)
    assert pic.near("a", 0.0, 0.0, 10.0) == []
    pic.feed("b", tel(5.0, 0.0, 2), 0.1)
    assert [p.agent for p in pic.near("a", 0.0, 0.0, 10.0)] == ["b"]
    assert not pic.feed("b", tel(50.0, 0.0, 2), 0.2)  # the same utime again: refused
    assert [p.agent for p in pic.near("a", 0.0, 0.0, 10.0)] == ["b"]


def test_stale_agents_leave_the_grid_but_every_query_gets_them() -> None:
    pic = picture()
    pic.feed("a", tel(0.0, 0.0, 1), 0.0)
    pic.feed("far", tel(500.0, 0.0, 1), 0.0)
    pic.sweep(0.5)
    assert pic.near("a", 0.0, 0.0, 10.0) == []
    pic.feed("a", tel(0.0, 0.0, 2), 2.0)
    pic.sweep(2.0)  # far: 2 s silent, stale: handed to every query, wherever it was
    assert [p.agent for p in pic.near("a", 0.0, 0.0, 10.0)] == ["far"]
    assert pic.fresh("a") == 0
    pic.feed("far", tel(400.0, 0.0, 3), 2.5)  # heard again: back in the grid, off the stale list
    assert pic.near("a", 0.0, 0.0, 10.0) == [] and pic.fresh("a") == 1
    pic.feed("a", tel(0.0, 0.0, 4), 9.0)
    pic.sweep(9.0)  # far: 6.5 s silent > forget_after
    assert len(pic) == 1 and pic.near("a", 0.0, 0.0, 10.0) == []


def test_bad_telemetry_and_nameless_agents_are_refused() -> None:
    pic = SwarmPicture(cell=10.0, stale_after=1.0, forget_after=5.0)
    bad = tel(0.0, 0.0, 1)
    bad.lat = math.nan
    assert not pic.feed("a", bad, 0.0) and pic.frame is None  # no frame from a NaN
    assert not pic.feed("", tel(0.0, 0.0, 1), 0.0)
    assert pic.feed("a", tel(3.0, 4.0, 1), 0.0)
    assert pic.frame is not None  # the first good position is the origin
    assert pic.near("b", 0.0, 0.0, 10.0)[0].north == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="cell"):
        SwarmPicture(cell=0.0, stale_after=1.0, forget_after=5.0)
