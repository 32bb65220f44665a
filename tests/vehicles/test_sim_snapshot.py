"""The sim's shortcuts against the full path, poll after poll and bit for bit: the snapshot
filled slot by slot without the dataclass's ``__init__`` (`telemetry.snapshot`), GUIDED flight's
steps on local variables (`Quadcopter._fly`) and a still vehicle's brake (`Quadcopter._brake`),
across set-points, uneven polls, battery edges and mode changes."""

from __future__ import annotations

import math
import random
from dataclasses import FrozenInstanceError, fields
from typing import Any

import pytest

from antalate_lcm.vehicles import AutopilotError, Frame, VehicleState
from antalate_lcm.vehicles.sim import SimAdapter
from antalate_lcm.vehicles.sim.params import shared
from tests.harness.clock import FakeClock

#: Near the simulated clock's start (core/simclock.py): its slots' differences are a hair off 50 ms.
T0 = 100_000.0


class _Counted(SimAdapter):
    """The sim as shipped, counting the polls its shortcuts took."""

    __slots__ = ("flights",)

    def _fly(self, dt: float, max_step: float) -> float:
        self.flights = getattr(self, "flights", 0) + 1
        return super()._fly(dt, max_step)


class _FullPath(SimAdapter):
    """The sim without the shortcuts: every step through `_step` (and the brake's lag on both
    axes), every snapshot made by the dataclass's constructor."""

    __slots__ = ()

    def _fly(self, dt: float, max_step: float) -> float:
        return dt  # nothing flown: `_advance` steps all of ``dt`` with `_step`

    def state(self) -> VehicleState:
        state = super().state()
        return VehicleState(**{f.name: getattr(state, f.name) for f in fields(VehicleState)})

    def _brake(self, h: float) -> None:  # the lag of both axes, still or not
        self.vn, dn = self._lag(self.vn, 0.0, h)
        self.ve, de = self._lag(self.ve, 0.0, h)
        self.north += dn
        self.east += de


def _bits(sim: SimAdapter, state: VehicleState) -> list[str]:
    """Everything reported and kept, floats by their repr (-0.0 and nan as themselves)."""
    kept = ("north", "east", "alt", "vn", "ve", "vd", "heading", "battery", "mode", "in_air", "armed")
    reported = [repr(getattr(state, f.name)) for f in fields(VehicleState)]
    return [type(state).__name__, *reported] + [repr(getattr(sim, k)) for k in (*kept, "sim_time")]


def _act(sim: SimAdapter, i: int, r: random.Random) -> None:
    """The same commands to both sims: arm and take off, set-points, an RTL or LAND, the battery
    emptied in the air, a write of the position on the ground, another flight."""
    try:
        if i in (20, 1300):
            sim.arm()
            sim.takeoff(r.choice([2.0, 5.0]))
        elif i == 15:
            sim.north = -0.0  # written from outside: the copied snapshot must see it
        elif i > 80 and r.random() < 0.4:
            sim.set_velocity(
                r.choice([2.0, 0.0, -3.0, 15.0, 8.0]),
                r.choice([0.0, 0.3, 9.0, -12.0]),
                r.choice([0.0, 0.0, -0.5, 0.3, 3.0, -4.0]),  # down 3 m/s lands it now and then
                r.choice([0.0, 40.0, -10.0, 500.0]),
                r.choice([Frame.BODY, Frame.NED]),
            )
        if i == 900:
            sim.rtl() if r.random() < 0.5 else sim.land()
        elif i == 1150:
            sim.trigger_failsafe("brake")
        elif i == 1200:
            sim.set_battery(0.0 if r.random() < 0.5 else 0.004)
    except AutopilotError:
        pass  # refused alike by both (takeoff on an empty battery)


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"battery": 2.0, "drain_flying": 3.0},  # runs out in the air: LAND mid-poll
        {"max_speed": 2.0, "tau": 0.3, "velocity_hold": 0.12},  # clamps; set-points expire mid-poll
        {
            "cells": 0,
            "battery_warning_at": 99.9,
            "voltage_sag": 0.2,
            "drain_idle": 30.0,
        },  # warns on the ground
        {"max_step": 0.02, "time_scale": 3.0},
        {"battery": 0.01, "drain_idle": 60.0, "battery_warning_at": 50.0},  # empties on the ground
    ],
)
@pytest.mark.parametrize("grid", [True, False], ids=["simulated-time", "uneven"])
def test_shortcuts_are_the_full_path_bit_for_bit(params: dict[str, Any], grid: bool) -> None:
    r = random.Random(len(params) * 2 + grid)
    clocks = (FakeClock(T0), FakeClock(T0))
    shortcut, full = _Counted(params, clock=clocks[0]), _FullPath(params, clock=clocks[1])
    sims: tuple[SimAdapter, ...] = (shortcut, full)
    for sim in sims:
        sim.connect()
    slot = round(T0 * 1000)
    for i in range(1500):
        # Simulated time moves in whole ms (a float sum); the wall clock anywhere up to 0.2 s.
        slot += r.choice([50, 50, 50, 100, 0, 150])
        dt = (slot / 1000 - clocks[0].t) if grid else r.uniform(0.0, 0.2)
        seed = r.random()
        seen = []
        for sim, clock in zip(sims, clocks, strict=True):
            clock.advance(dt)
            _act(sim, i, random.Random(seed))
            seen.append(_bits(sim, sim.state()))
        assert seen[0] == seen[1], i
    flew = params.get("battery", 100.0) > 1.0  # else empty on the ground before the takeoff
    assert getattr(shortcut, "flights", 0) > (100 if flew else -1)


def test_a_filled_snapshot_is_a_whole_vehicle_state_of_its_own() -> None:
    clock = FakeClock(T0)
    sim = SimAdapter({"battery_warning_at": 100.0}, clock=clock)
    sim.connect()
    clock.advance(0.05)
    first = sim.state()
    clock.advance(0.05)
    second = sim.state()
    assert type(second) is VehicleState and second is not first
    assert second.battery < first.battery and second.voltage < first.voltage
    assert second.battery_warning.startswith("battery low")
    assert second == VehicleState(**{f.name: getattr(second, f.name) for f in fields(VehicleState)})
    assert hash(second) == hash(VehicleState(**{f.name: getattr(second, f.name) for f in fields(second)}))
    with pytest.raises(FrozenInstanceError):
        second.battery = 1.0  # type: ignore[misc]
    clock.advance(0.0)
    sim.vd = -0.0  # a write the snapshot must not hide: equal to 0.0, yet another value
    assert repr(sim.state().vd) == "-0.0"


def test_a_turn_through_north_by_a_sliver_of_a_step_wraps_as_wrap_360() -> None:
    """`_fly`'s inline `wrap_360` at its edge: -3e-15 deg is 360.0 after the addition, reported 0.0."""
    states = []
    for cls in (_Counted, _FullPath):
        clock = FakeClock(0.0)
        sim = cls({}, clock=clock)
        sim.connect()
        assert sim.arm()
        sim.takeoff(5.0)
        clock.advance(3.0)
        sim.state()
        sim.heading = 0.5
        sim.set_velocity(0.0, 0.0, 0.0, -10.0, Frame.BODY)
        clock.t = math.nextafter(3.05, 4.0)  # a step of 0.05 s to heading 0.0, then a sliver
        states.append(sim.state())
    assert [repr(s.heading) for s in states] == ["0.0", "0.0"]


def test_sims_of_one_config_read_one_tuple_of_parameters_to_the_bit() -> None:
    """`params.shared` (`base.shared.shared_value` keyed by repr): the poll's parameter tuples are one object across sims of one config, and
    equal to the tuples a sim of its own builds; a value equal but not the same (-0.0, 1 and 1.0)
    keeps a tuple of its own."""
    clock = FakeClock(T0)
    one, two = SimAdapter({"home_lat": 1.0}, clock=clock), SimAdapter({"home_lat": 2.0}, clock=clock)
    for name in ("_step_lag", "_drain", "_battery_params"):
        assert getattr(one, name) is getattr(two, name)
    p = one._p
    decay = math.exp(-p.max_step / p.tau)
    assert one._step_lag == (p.max_step, decay, p.tau * (1.0 - decay))
    assert one._drain == (p.drain_idle, p.drain_flying)
    assert one._battery_params == (p.cells, p.voltage_sag, p.battery_warning_at)
    sag = one._battery_params  # (4, 0.0, 0.0)
    minus = shared((4, -0.0, 0.0))
    assert minus == sag and minus is not sag and repr(minus[1]) == "-0.0"
    assert shared((1.0, 2.0)) is shared((1.0, 2.0)) and shared((1, 2.0)) is not shared((1.0, 2.0))
