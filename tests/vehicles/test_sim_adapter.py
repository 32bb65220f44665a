"""SimAdapter kinematics and faults (link loss with a duration, autopilot failsafes, state() raising,
voltage per cell, battery warning) on a fake clock; the autopilot contract and registry."""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import FrozenInstanceError, asdict, fields
from typing import Any

import pytest

from antalate_lcm.base import geo
from antalate_lcm.base.errors import PluginNotFound
from antalate_lcm.vehicles import (
    AutopilotError,
    FlightMode,
    Frame,
    UnknownAdapterError,
    VehicleAdapter,
    VehicleState,
    available_adapters,
    load_adapter,
)
from antalate_lcm.vehicles.sim import DEFAULTS, SimAdapter
from tests.harness.clock import FakeClock

HOME = (32.7767, 35.0231)


#: Where the simulator's fake clock starts (s).
T0 = 1000.0


def make(**params: Any) -> tuple[SimAdapter, FakeClock]:
    clock = FakeClock(T0)
    sim = SimAdapter(params, clock=clock)
    sim.connect()
    return sim, clock


def run(sim: SimAdapter, clock: FakeClock, seconds: float, poll: float = 0.1) -> VehicleState:
    """Advance time while polling state() like the HLC does (the sim only integrates when called)."""
    steps = round(seconds / poll)
    for _ in range(steps):
        clock.advance(poll)
        sim.state()
    return sim.state()


def airborne(alt: float = 10.0, **params: Any) -> tuple[SimAdapter, FakeClock]:
    sim, clock = make(**params)
    assert sim.arm()
    sim.takeoff(alt)
    run(sim, clock, alt / params.get("climb_rate", 2.5) + 0.2)
    assert sim.state().alt == pytest.approx(alt)
    return sim, clock


# -------------------------------------------------------------------------------- contract


def test_contract_basics() -> None:
    assert SimAdapter.name == "sim"
    assert issubclass(SimAdapter, VehicleAdapter)
    with pytest.raises(TypeError):
        VehicleAdapter()  # type: ignore[abstract]
    assert int(Frame.BODY) == 0 and int(Frame.NED) == 1


def test_state_before_connect_and_after_close() -> None:
    clock = FakeClock(T0)
    sim = SimAdapter({}, clock=clock)
    s = sim.state()
    assert not s.connected and s.link_age == math.inf
    with pytest.raises(AutopilotError, match="not connected"):
        sim.arm()
    sim.connect()
    assert sim.state().connected
    sim.close()
    assert not sim.state().connected
    sim.close()  # idempotent


def test_initial_state_at_home() -> None:
    sim, _ = make()
    s = sim.state()
    assert (s.lat, s.lon) == pytest.approx(HOME)
    assert s.alt == 0.0 and s.battery == 100.0 and s.link_age == 0.0
    assert s.landed and not s.armed and not s.in_air
    assert s.mode == "GUIDED" and s.autonomous and s.flight_mode is FlightMode.GUIDED
    with pytest.raises(FrozenInstanceError):
        s.alt = 3.0  # type: ignore[misc]


def test_snapshot_is_a_whole_vehicle_state() -> None:
    """The sim builds its 20-a-second snapshots without the dataclass's __init__ (sim.telemetry.snapshot): each
    holds every field, the same state the constructor makes, and stays frozen and hashable."""
    sim, clock = make(cells=4, battery_warning_at=99.99)
    assert sim.arm()
    sim.takeoff(5.0)
    for s in (sim.state(), run(sim, clock, 1.0), run(sim, clock, 3.0)):
        assert type(s) is VehicleState and not hasattr(s, "__dict__")
        assert all(hasattr(s, f.name) for f in fields(VehicleState))
        rebuilt = VehicleState(**asdict(s))
        assert rebuilt == s and hash(rebuilt) == hash(s) and repr(rebuilt) == repr(s)
    assert s.in_air and s.battery_warning and math.isfinite(s.voltage)
    with pytest.raises(FrozenInstanceError):
        s.battery = 50.0  # type: ignore[misc]


def test_configurable_home_and_heading() -> None:
    sim, _ = make(home_lat=-33.8688, home_lon=151.2093, heading=-90.0)
    s = sim.state()
    assert (s.lat, s.lon) == pytest.approx((-33.8688, 151.2093))
    assert s.heading == pytest.approx(270.0)


def test_default_clock_is_monotonic() -> None:
    sim = SimAdapter({})
    assert sim.clock is time.monotonic


def test_vehicle_state_defaults_and_derivations() -> None:
    empty = VehicleState()
    assert not empty.connected and empty.link_age == math.inf and empty.battery == -1.0
    assert not empty.battery_known and empty.landed
    assert VehicleState(autonomous=False).flight_mode is FlightMode.MANUAL
    assert VehicleState(autonomous=True).flight_mode is FlightMode.GUIDED
    assert VehicleState(flight_mode=FlightMode.RTL).flight_mode is FlightMode.RTL
    assert not VehicleState(armed=True).landed and not VehicleState(in_air=True).landed


@pytest.mark.parametrize(
    "params, match",
    [
        ({"hom_lat": 1.0}, "hom_lat"),
        ({"tau": 0.0}, "tau"),
        ({"climb_rate": -1.0}, "climb_rate"),
        ({"battery": 120.0}, "battery"),
        ({"time_scale": float("nan")}, "time_scale"),
    ],
)
def test_bad_params_raise(params: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SimAdapter(params, clock=FakeClock(T0))


# -------------------------------------------------------------------------------- kinematics


def test_takeoff_climbs_at_the_climb_rate() -> None:
    sim, clock = make(climb_rate=2.5)
    assert sim.arm()
    assert sim.state().armed and not sim.state().in_air
    sim.takeoff(10.0)
    s = run(sim, clock, 2.0)
    assert s.alt == pytest.approx(5.0, abs=1e-6)
    assert s.vd == pytest.approx(-2.5) and s.in_air and s.armed and s.mode == "GUIDED"
    s = run(sim, clock, 2.0)
    assert s.alt == pytest.approx(10.0)
    s = run(sim, clock, 5.0)
    assert s.alt == pytest.approx(10.0) and s.vd == 0.0  # holds, no overshoot
    assert (s.lat, s.lon) == pytest.approx(HOME)


def test_takeoff_preconditions() -> None:
    sim, _ = make()
    with pytest.raises(AutopilotError, match="not armed"):
        sim.takeoff(10.0)
    sim.arm()
    for bad in (0.0, -3.0, math.nan):
        with pytest.raises(AutopilotError, match="altitude"):
            sim.takeoff(bad)
    sim.takeoff(5.0)
    with pytest.raises(AutopilotError, match="already flying"):
        sim.takeoff(5.0)


def test_velocity_response_is_first_order_with_time_constant() -> None:
    sim, clock = airborne(tau=0.5)
    sim.set_velocity(4.0, 0.0, 0.0, 0.0, Frame.NED)
    s = run(sim, clock, 0.5, poll=0.05)
    assert s.vn == pytest.approx(4.0 * (1.0 - math.exp(-1.0)), abs=1e-6)
    sim.set_velocity(4.0, 0.0, 0.0, 0.0, Frame.NED)
    s = run(sim, clock, 2.0, poll=0.05)
    assert s.vn == pytest.approx(4.0 * (1.0 - math.exp(-5.0)), abs=1e-6)
    assert s.ve == pytest.approx(0.0, abs=1e-9) and s.alt == pytest.approx(10.0)
    north, east = geo.local_ne(*HOME, s.lat, s.lon)
    # Distance of a first-order response: v (t - tau (1 - e^(-t/tau))).
    assert north == pytest.approx(4.0 * (2.5 - 0.5 * (1.0 - math.exp(-5.0))), abs=0.01)
    assert abs(east) < 0.01


@pytest.mark.parametrize("frame, yaw_rate, tolerance", [(Frame.NED, 0.0, 1e-9), (Frame.BODY, 10.0, 0.05)])
def test_integration_does_not_depend_on_the_polling_rate(
    frame: Frame, yaw_rate: float, tolerance: float
) -> None:
    """Exact for a constant NED set-point; a turning body frame differs by centimetres."""
    finals = []
    for poll in (0.01, 0.1, 1.0):
        sim, clock = airborne()
        sim.set_velocity(3.0, 1.0, -0.5, yaw_rate, frame)
        s = run(sim, clock, 2.0, poll=poll)
        north, east = geo.local_ne(*HOME, s.lat, s.lon)
        finals.append((north, east, s.alt, s.heading, s.vn, s.ve, s.vd))
    assert finals[0] == pytest.approx(finals[1], abs=tolerance)
    assert finals[0] == pytest.approx(finals[2], abs=tolerance)


def test_body_frame_follows_heading_and_yaw_rate_turns() -> None:
    sim, clock = airborne(heading=90.0)
    sim.set_velocity(2.0, 0.0, 0.0, 0.0, Frame.BODY)  # forward while facing east
    s = run(sim, clock, 2.5)
    assert s.ve == pytest.approx(2.0, rel=0.01) and abs(s.vn) < 1e-9
    sim.set_velocity(0.0, 0.0, 0.0, 30.0, Frame.BODY)
    s = run(sim, clock, 2.0)
    assert s.heading == pytest.approx(150.0)
    sim.set_velocity(0.0, 0.0, 0.0, -100.0, Frame.NED)
    s = run(sim, clock, 2.0)
    assert s.heading == pytest.approx(geo.wrap_360(150.0 - 200.0))


def test_velocity_limits() -> None:
    sim, clock = airborne(max_speed=6.0, climb_rate=2.0, descent_rate=1.0)
    sim.set_velocity(30.0, 40.0, -9.0, 0.0, Frame.NED)  # 50 m/s horizontal, 9 m/s up
    s = run(sim, clock, 2.5)
    assert math.hypot(s.vn, s.ve) == pytest.approx(6.0, rel=0.01)
    assert s.ve / s.vn == pytest.approx(40.0 / 30.0)
    assert s.vd == pytest.approx(-2.0, rel=0.01)
    sim.set_velocity(0.0, 0.0, 5.0, 0.0, Frame.NED)
    s = run(sim, clock, 2.5)
    assert s.vd == pytest.approx(1.0, abs=0.03)  # from -2 m/s: 1 - 3 e^-5


def test_velocity_setpoint_expires_like_arducopter() -> None:
    sim, clock = airborne(velocity_hold=3.0)
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)
    assert run(sim, clock, 2.9).vn == pytest.approx(3.0, rel=0.01)
    assert abs(run(sim, clock, 4.0).vn) < 0.01


class _AlwaysSteps(SimAdapter):
    """The sim without its hovering shortcut: every GUIDED poll through `_step`."""

    __slots__ = ()

    def _hover(self, dt: float) -> bool:
        return False


class _CountsHovers(SimAdapter):
    __slots__ = ("hovers",)

    def _hover(self, dt: float) -> bool:
        taken = super()._hover(dt)
        self.hovers = getattr(self, "hovers", 0) + taken
        return taken


_COMPARED = (
    "north",
    "east",
    "alt",
    "vn",
    "ve",
    "vd",
    "heading",
    "battery",
    "mode",
    "in_air",
    "armed",
    "sim_time",
)


@pytest.mark.parametrize("north", [0.0, -0.0, 12.5])
def test_hovering_shortcut_is_the_step_it_skips(north: float) -> None:
    """A still, uncommanded hover skips `_step` (its lag from zero to zero): bit for bit the same
    vehicle, poll after poll, through a set-point that starts and expires, an uneven poll interval
    and the battery running out in the air."""
    sims: list[tuple[SimAdapter, FakeClock]] = []
    classes: tuple[type[SimAdapter], ...] = (_CountsHovers, _AlwaysSteps)
    for cls in classes:
        clock = FakeClock(T0)
        made = cls({"battery": 2.0, "drain_flying": 3.0}, clock=clock)
        made.connect()
        made.north = north
        assert made.arm()
        made.takeoff(5.0)
        sims.append((made, clock))
    for i in range(1000):
        seen = []
        for sim, clock in sims:
            if i == 200:
                sim.set_velocity(0.5, 0.0, 0.0, 0.0, Frame.NED)
            clock.advance(0.051 if i % 3 else 0.049)
            seen.append((sim.state(), [repr(getattr(sim, name)) for name in _COMPARED]))
        assert seen[0] == seen[1], i
    shortcut = sims[0][0]
    assert isinstance(shortcut, _CountsHovers) and shortcut.hovers > 100  # the hover before the set-point
    assert shortcut.battery == 0.0 and not shortcut.in_air  # and the battery ran out: LAND, alike


def test_descending_to_the_ground_in_guided_touches_down_then_auto_disarms() -> None:
    sim, clock = airborne(alt=2.0, auto_disarm_delay=10.0)
    for _ in range(5):
        sim.set_velocity(0.0, 0.0, 1.5, 0.0, Frame.NED)
        run(sim, clock, 1.0)
    s = sim.state()
    assert s.alt == 0.0 and not s.in_air and s.armed
    s = run(sim, clock, 10.0)
    assert not s.armed and s.landed


def test_velocity_ignored_outside_guided_flight_and_non_finite_refused() -> None:
    sim, clock = make()
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)  # on the ground: ignored
    assert run(sim, clock, 1.0).vn == 0.0
    sim, clock = airborne()
    with pytest.raises(AutopilotError, match="non-finite"):
        sim.set_velocity(math.nan, 0.0, 0.0, 0.0, Frame.NED)
    sim.land()
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)  # in LAND: ignored
    assert run(sim, clock, 1.0).vn == 0.0


def test_land_descends_at_the_descent_rate_and_disarms() -> None:
    sim, clock = airborne(alt=9.0, descent_rate=1.5, land_disarm_delay=0.5)
    sim.land()
    s = run(sim, clock, 2.0)
    assert s.mode == "LAND" and s.flight_mode is FlightMode.LANDING and s.autonomous
    assert s.alt == pytest.approx(6.0, abs=1e-6) and s.vd == pytest.approx(1.5)
    s = run(sim, clock, 4.0)
    assert s.alt == 0.0 and not s.in_air and s.armed  # touched down, disarm pending
    s = run(sim, clock, 0.6)
    assert s.landed


def test_rtl_returns_home_then_lands() -> None:
    sim, clock = airborne(alt=10.0, rtl_speed=5.0, descent_rate=2.0)
    for _ in range(10):  # fly 2 m/s north-east for 10 s
        sim.set_velocity(2.0, 2.0, 0.0, 0.0, Frame.NED)
        run(sim, clock, 1.0)
    s = sim.state()
    dist = geo.distance(*HOME, s.lat, s.lon)
    assert dist > 20.0
    sim.rtl()
    s = run(sim, clock, 1.0)
    assert s.mode == "RTL" and s.flight_mode is FlightMode.RTL
    assert math.hypot(s.vn, s.ve) == pytest.approx(5.0)
    assert geo.bearing(s.lat, s.lon, *HOME) == pytest.approx(225.0, abs=1.0)
    assert s.alt == pytest.approx(10.0)  # returns at altitude
    s = run(sim, clock, dist / 5.0)
    assert geo.distance(*HOME, s.lat, s.lon) < 0.01
    s = run(sim, clock, 10.0 / 2.0 + 1.0)
    assert s.landed and s.alt == 0.0
    assert geo.distance(*HOME, s.lat, s.lon) < 0.01  # no drift during the descent
    assert s.mode == "RTL"


def test_rtl_climbs_to_rtl_altitude_first() -> None:
    sim, clock = airborne(alt=5.0, rtl_altitude=15.0, climb_rate=2.5)
    sim.set_velocity(5.0, 0.0, 0.0, 0.0, Frame.NED)
    run(sim, clock, 3.0)
    sim.rtl()
    s = run(sim, clock, 2.0)
    assert s.alt == pytest.approx(10.0, abs=1e-6) and s.vn == 0.0


def test_land_and_rtl_on_the_ground_disarm() -> None:
    for command in ("land", "rtl"):
        sim, _ = make()
        sim.arm()
        getattr(sim, command)()
        assert sim.state().landed


def test_auto_disarm_when_armed_and_idle() -> None:
    sim, clock = make(auto_disarm_delay=10.0)
    sim.arm()
    assert run(sim, clock, 9.9).armed
    assert not run(sim, clock, 0.2).armed


def test_disarm() -> None:
    sim, _ = airborne()
    with pytest.raises(AutopilotError, match="in the air"):
        sim.disarm()
    sim, _ = make()
    sim.arm()
    sim.disarm()
    assert sim.state().landed


# -------------------------------------------------------------------------------- battery


def test_battery_drains_while_flying_and_idle() -> None:
    sim, clock = make(drain_flying=4.0, drain_idle=0.5)
    s = run(sim, clock, 60.0, poll=1.0)
    assert s.battery == pytest.approx(99.5)
    sim.arm()
    sim.takeoff(5.0)
    s = run(sim, clock, 60.0, poll=1.0)
    assert s.battery == pytest.approx(95.5, abs=1e-6)


def test_set_battery_and_initial_level() -> None:
    sim, clock = make(battery=30.0, drain_idle=0.0)
    assert sim.state().battery == 30.0
    sim.set_battery(12.5)
    assert run(sim, clock, 1.0).battery == 12.5
    with pytest.raises(ValueError):
        sim.set_battery(-3.0)


def test_empty_battery_forces_a_landing() -> None:
    sim, clock = airborne(battery=5.0, drain_flying=60.0)  # 1 %/s: empty 5 s after takeoff
    assert sim.state().mode == "GUIDED"
    s = run(sim, clock, 1.0)
    assert s.battery == 0.0
    assert s.mode == "LAND" and s.flight_mode is FlightMode.LANDING


def test_empty_battery_refuses_arming() -> None:
    sim, _ = make(battery=0.0)
    assert sim.arm() is False


# -------------------------------------------------------------------------------- faults


def test_link_loss_freezes_state_and_ages_the_link() -> None:
    sim, clock = airborne()
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)
    before = run(sim, clock, 1.0)
    sim.set_link_loss(True)
    clock.advance(2.5)
    s = sim.state()
    assert s.link_age == pytest.approx(2.5)
    assert (s.lat, s.lon, s.vn) == (before.lat, before.lon, before.vn)  # nothing new is heard
    for call in (
        sim.arm,
        sim.land,
        sim.rtl,
        lambda: sim.takeoff(3.0),
        lambda: sim.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.NED),
    ):
        with pytest.raises(AutopilotError, match="link lost"):
            call()
    sim.set_link_loss(False)
    s = sim.state()
    assert s.link_age == 0.0
    assert geo.distance(before.lat, before.lon, s.lat, s.lon) > 1.0  # it flew on meanwhile


def test_link_loss_from_the_start() -> None:
    sim, clock = make(link_loss=True)
    clock.advance(5.0)
    s = sim.state()
    assert s.connected and s.link_age == math.inf


@pytest.mark.parametrize(
    "mode, name, flight_mode",
    [
        ("rtl", "RTL", FlightMode.RTL),
        ("land", "LAND", FlightMode.LANDING),
        ("brake", "BRAKE", FlightMode.HOLD),
    ],
)
def test_autopilot_failsafe_reports_its_reason_until_commanded_or_landed(
    mode: str, name: str, flight_mode: FlightMode
) -> None:
    sim, clock = airborne()
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)
    run(sim, clock, 1.0)
    sim.trigger_failsafe(mode, "fence breach")
    s = run(sim, clock, 2.0)
    assert (s.mode, s.flight_mode, s.failsafe) == (name, flight_mode, "fence breach")
    assert s.autonomous  # the autopilot's own logic, not a pilot
    if mode == "brake":
        assert s.in_air and abs(s.vd) < 1e-9 and math.hypot(s.vn, s.ve) < 0.1  # stopped, holding
        sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)  # ignored outside GUIDED
        assert math.hypot(run(sim, clock, 1.0).vn, 0.0) < 0.1
        sim.land()  # the operator's LAND clears it
        assert sim.state().failsafe == "" and sim.state().mode == "LAND"
    else:
        s = run(sim, clock, 20.0)
        assert s.landed and s.failsafe == ""  # touched down: over


def test_failsafe_on_the_ground_disarms_and_unknown_modes_refused() -> None:
    sim, clock = make()
    assert sim.arm()
    sim.trigger_failsafe("land", "EKF failsafe")
    assert not sim.state().armed
    with pytest.raises(ValueError, match="failsafe mode"):
        sim.trigger_failsafe("loiter", "x")


def test_scheduled_failsafe() -> None:
    sim, clock = airborne(1.0, failsafe_after=2.0, failsafe_mode="brake", failsafe_reason="fence breach")
    assert sim.state().failsafe == ""
    s = run(sim, clock, 2.0)
    assert s.failsafe == "fence breach" and s.mode == "BRAKE"


def test_scheduled_link_loss_with_a_duration_comes_back() -> None:
    sim, clock = airborne(1.0, link_loss_after=1.0, link_loss_for=3.0)  # 0.6 s flown
    s = run(sim, clock, 2.0)
    assert s.link_age > 0.5
    s = run(sim, clock, 2.5)
    assert s.link_age == 0.0 and s.in_air
    s = run(sim, clock, 10.0)
    assert s.link_age == 0.0  # fires once


def test_state_error_raises_until_cleared_and_the_vehicle_flies_on() -> None:
    sim, clock = airborne()
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)
    before = run(sim, clock, 0.5)
    sim.set_state_error("bus error")
    for _ in range(10):
        clock.advance(0.1)
        with pytest.raises(RuntimeError, match="bus error"):
            sim.state()
    sim.set_state_error(None)
    after = sim.state()
    assert geo.distance(before.lat, before.lon, after.lat, after.lon) > 1.0


def test_scheduled_state_error_for_a_while() -> None:
    sim, clock = airborne(1.0, state_error_after=1.0, state_error_for=2.0)  # 0.6 s flown
    run(sim, clock, 0.3)
    raised = 0
    for _ in range(30):
        clock.advance(0.1)
        try:
            sim.state()
        except RuntimeError as exc:
            assert "simulated adapter fault" in str(exc)
            raised += 1
    assert 18 <= raised <= 21
    assert sim.state().in_air


def test_voltage_per_cell_and_sag() -> None:
    sim, clock = make(battery=50.0, cells=4, voltage_sag=0.3)
    s = sim.state()
    assert s.cells == 4 and s.cell_voltage == pytest.approx(3.8)  # 3.4 + 0.8 x 50%
    assert sim.arm()
    sim.takeoff(5.0)
    s = run(sim, clock, 0.5)
    assert s.in_air and s.cell_voltage == pytest.approx(3.5, abs=0.01)  # sagging under load
    sim, _ = make(cells=0)
    assert math.isnan(sim.state().voltage) and math.isnan(sim.state().cell_voltage)


def test_battery_warning_at() -> None:
    sim, clock = make(battery=31.0, battery_warning_at=30.0)
    assert sim.state().battery_warning == ""
    sim.set_battery(30.0)
    assert "battery low" in sim.state().battery_warning


@pytest.mark.parametrize(
    "params, match",
    [
        ({"failsafe_mode": "loiter"}, "failsafe_mode"),
        ({"link_loss_for": -1.0}, "link_loss_for"),
        ({"cells": -2}, "cells"),
        ({"voltage_sag": float("nan")}, "voltage_sag"),
    ],
)
def test_bad_fault_params_raise(params: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SimAdapter(params, clock=FakeClock(T0))


def test_refuse_arm_from_params_and_api() -> None:
    sim, _ = make(refuse_arm=True)
    assert sim.arm() is False and not sim.state().armed
    sim.set_refuse_arm(False)
    assert sim.arm() is True
    sim, _ = make()
    sim.set_refuse_arm(True)
    assert sim.arm() is False


def test_pilot_takeover_then_the_pilot_lands() -> None:
    sim, clock = airborne(alt=6.0, takeover_land_delay=2.0, descent_rate=1.5)
    sim.set_velocity(3.0, 0.0, 0.0, 0.0, Frame.NED)
    run(sim, clock, 1.0)
    sim.pilot_takeover()
    s = sim.state()
    assert s.mode == "LOITER" and not s.autonomous and s.flight_mode is FlightMode.MANUAL
    sim.set_velocity(0.0, 0.0, -2.0, 0.0, Frame.NED)  # ignored: the pilot flies
    s = run(sim, clock, 1.9)
    assert s.alt == pytest.approx(6.0) and s.in_air
    s = run(sim, clock, 0.1 + 4.0 + 0.1)
    assert s.alt == 0.0 and not s.in_air
    s = run(sim, clock, 1.0)
    assert s.landed and s.mode == "LOITER"
    assert sim.arm()  # arming again puts it back in GUIDED
    assert sim.state().mode == "GUIDED"


def test_pilot_takeover_without_autoland_hovers() -> None:
    sim, clock = airborne(takeover_autoland=False)
    sim.pilot_takeover()
    assert run(sim, clock, 30.0).alt == pytest.approx(10.0)
    sim2, clock2 = airborne()
    sim2.pilot_takeover(auto_land=False)  # the API overrides the param (default: autoland)
    assert run(sim2, clock2, 30.0).in_air


def test_takeoff_refused_while_a_pilot_has_the_vehicle() -> None:
    sim, _ = make()
    sim.arm()
    sim.pilot_takeover()  # on the ground: only the mode changes
    with pytest.raises(AutopilotError, match="GUIDED"):
        sim.takeoff(3.0)


def test_time_scale() -> None:
    sim, clock = make(time_scale=10.0)
    sim.arm()
    sim.takeoff(10.0)
    s = run(sim, clock, 0.2, poll=0.05)
    assert s.alt == pytest.approx(5.0)
    assert sim.sim_time == pytest.approx(2.0)
    sim.set_time_scale(1.0)
    s = run(sim, clock, 1.0)
    assert s.alt == pytest.approx(7.5)
    with pytest.raises(ValueError):
        sim.set_time_scale(0.0)


def test_time_does_not_advance_between_calls_and_never_runs_backwards() -> None:
    sim, clock = airborne()
    t = sim.sim_time
    clock.t -= 5.0  # a misbehaving clock must not integrate backwards
    sim.state()
    assert sim.sim_time == t


def test_many_idle_sims_are_cheap() -> None:
    clock = FakeClock(T0)
    sims = [SimAdapter({"home_lat": 32.0 + i * 1e-4}, clock=clock) for i in range(200)]
    for sim in sims:
        sim.connect()
    clock.advance(3600.0)  # an hour on the ground between calls
    started = time.perf_counter()
    states = [sim.state() for sim in sims]
    assert time.perf_counter() - started < 0.5
    assert all(s.battery == pytest.approx(100.0 - 0.1 * 60.0) for s in states)


def test_every_documented_param_is_accepted() -> None:
    SimAdapter(dict(DEFAULTS), clock=FakeClock(T0))


# -------------------------------------------------------------------------------- registry


def test_registry_lists_the_shipped_adapters() -> None:
    names = available_adapters()
    assert {"sim", "tello", "mavlink"} <= set(names)
    assert names["sim"] == "antalate_lcm.vehicles.sim:SimAdapter"


def test_load_by_name_and_by_module_path() -> None:
    assert load_adapter("sim") is SimAdapter
    assert load_adapter("antalate_lcm.vehicles.sim:SimAdapter") is SimAdapter


def test_unknown_name_lists_the_available_ones() -> None:
    with pytest.raises(UnknownAdapterError) as info:
        load_adapter("simm")
    message = str(info.value)
    assert "simm" in message and "sim" in message and "mavlink" in message and "tello" in message
    assert isinstance(info.value, PluginNotFound) and isinstance(info.value, LookupError)


@pytest.mark.parametrize(
    "target, match",
    [
        ("antalate_lcm.nope:Thing", "cannot load"),
        ("antalate_lcm.vehicles.sim:Nope", "cannot load"),
        ("antalate_lcm.vehicles.base:VehicleState", "not a subclass"),
    ],
)
def test_bad_module_paths(target: str, match: str) -> None:
    with pytest.raises(UnknownAdapterError, match=match):
        load_adapter(target)


def test_an_adapter_of_a_user_keeps_its_dict_weakrefs_and_mixins() -> None:
    """`VehicleAdapter` declares empty slots (the sim lists its attributes in its own): an adapter a
    user writes, with a mixin and attributes of its own, has a __dict__ and weakrefs as ever, and so
    does a subclass of the sim."""

    class Tagged:
        def tag(self) -> str:
            return f"{self.name}:{self.serial}"  # type: ignore[attr-defined]

    class Mine(Tagged, VehicleAdapter):
        name = "mine"

        def __init__(self) -> None:
            super().__init__({"port": 1})
            self.serial = "A1"
            self.last_refusal = "not yet"

        def connect(self) -> None: ...
        def close(self) -> None: ...
        def arm(self) -> bool:
            return False

        def disarm(self) -> None: ...
        def takeoff(self, alt: float) -> None: ...
        def land(self) -> None: ...
        def rtl(self) -> None: ...
        def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None: ...
        def state(self) -> VehicleState:
            return VehicleState()

    mine = Mine()
    assert vars(mine) == {
        "params": {"port": 1},
        "clock": time.monotonic,
        "serial": "A1",
        "last_refusal": "not yet",
    }
    assert mine.tag() == "mine:A1" and weakref.ref(mine)() is mine

    class MySim(SimAdapter):
        pass

    sim = MySim(clock=FakeClock(0.0))
    sim.notes = "mine"  # type: ignore[attr-defined]
    assert vars(sim) == {"notes": "mine"} and weakref.ref(sim)() is sim
    sim.connect()
    assert sim.state().connected and SimAdapter().params == {}
