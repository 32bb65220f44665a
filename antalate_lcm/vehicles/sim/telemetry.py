"""`snapshot`: the `VehicleState` the simulated autopilot reports, 20 times a second per agent.

Position in WGS84 from the model's metres off home, ArduCopter's mode names mapped to
`FlightMode`, and the battery as a real pack reports it: a ``cells``-cell pack whose voltage per cell
falls linearly from 4.2 V (100%) to 3.4 V (0%), minus ``voltage_sag`` V per cell in the air (a tired
or cold pack sags under load while its percentage still reads well); ``cells = 0`` reports no
voltage. ``battery_warning_at`` (percent, 0 = never): at or below it the vehicle sets
`VehicleState.battery_warning` (its own low-battery verdict, like ArduPilot's
BATT_LOW_VOLT/BATT_LOW_MAH).
"""

from __future__ import annotations

import math

from antalate_lcm.vehicles.base import FlightMode, VehicleState
from antalate_lcm.vehicles.sim.physics import Quadcopter

__all__ = ["snapshot"]

_AUTONOMOUS_MODES = {
    "GUIDED": FlightMode.GUIDED,
    "LAND": FlightMode.LANDING,
    "RTL": FlightMode.RTL,
    "BRAKE": FlightMode.HOLD,  # ArduCopter's fence action: stop and hold
}
_MANUAL = FlightMode.MANUAL
_CELL_FULL, _CELL_EMPTY = 4.2, 3.4  # V per cell at 100% and 0%


_new = object.__new__
_set = object.__setattr__


def snapshot(v: Quadcopter) -> VehicleState:
    """What `v`'s autopilot reports now (connected, the link fresh: `faults` ages a lost one)."""
    # The state is built without the frozen dataclass's ``__init__``: its per-field
    # ``object.__setattr__`` took two thirds of a snapshot, and the sim makes 20 a second per agent;
    # the fresh dict below becomes the instance's own. Equal to ``VehicleState(**values)``
    # (tests/vehicles/test_sim_adapter.py checks it).
    battery = v.battery
    battery_params = v._battery_params
    cells, sag, warn_at = battery_params
    north = v.north
    east = v.east
    # A vehicle on the ground or hovering still reports the same values poll after poll but for
    # its battery: they come from a copy of the last still snapshot's dict when every value it was
    # made of is the same object now (an object is its value: no write can make the copy stale),
    # about half the work of building the dict anew (docs/simulator.md, "Issue 32, fifth pass";
    # tests/vehicles/test_sim_snapshot.py checks it bit for bit).
    n0, e0, alt0, heading0, vn0, ve0, vd0, armed0, in_air0, mode0, failsafe0, params0, moving = v._snapshot_of
    if (
        north is n0
        and east is e0
        and v.alt is alt0
        and v.heading is heading0
        and v.vn is vn0
        and v.ve is ve0
        and v.vd is vd0
        and v.armed is armed0
        and v.in_air is in_air0
        and v.mode is mode0
        and v._failsafe is failsafe0
        and battery_params is params0
    ):
        values = v._snapshot.copy()
        values["battery"] = battery
        if cells:
            if not in_air0:
                sag = 0.0
            values["voltage"] = cells * (_CELL_EMPTY + (_CELL_FULL - _CELL_EMPTY) * battery / 100.0 - sag)
        if warn_at:
            values["battery_warning"] = (
                f"battery low ({battery:.0f}% <= {warn_at:g}%)" if battery <= warn_at else ""
            )
        state = _new(VehicleState)
        _set(state, "__dict__", values)
        return state
    # lat/lon are recomputed only when the vehicle moved.
    if north != v._latlon_n or east != v._latlon_e:
        v._latlon_n = north
        v._latlon_e = east
        v._latlon = v.home.to_latlon(north, east)
    lat, lon = v._latlon
    armed = v.armed
    in_air = v.in_air
    mode = v.mode
    failsafe = v._failsafe
    if (
        armed is armed0
        and in_air is in_air0
        and mode is mode0
        and failsafe is failsafe0
        and battery_params is params0
    ):
        # Moving (a swarm in flight, 20 polls a second per agent): the last kept snapshot's dict
        # has the ten values that come from these five objects alone (connected, link_age, armed,
        # in_air, autonomous, mode, flight_mode, failsafe, cells, and battery_warning rewritten
        # below); the nine that move are written over a copy, which costs half the dict built
        # anew (docs/simulator.md, "Issue 32, sixth pass").
        values = moving.copy()
        values["lat"] = lat
        values["lon"] = lon
        values["alt"] = v.alt
        values["heading"] = v.heading
        values["vn"] = vn = v.vn
        values["ve"] = ve = v.ve
        values["vd"] = vd = v.vd
        values["battery"] = battery
        if cells:
            if not in_air:
                sag = 0.0
            values["voltage"] = cells * (_CELL_EMPTY + (_CELL_FULL - _CELL_EMPTY) * battery / 100.0 - sag)
        if warn_at:
            values["battery_warning"] = (
                f"battery low ({battery:.0f}% <= {warn_at:g}%)" if battery <= warn_at else ""
            )
        if not (vn or ve or vd):  # stopped (a hover): the still copy from the next poll on
            _keep(v, values, north, east, battery_params)
        state = _new(VehicleState)
        _set(state, "__dict__", values)
        return state
    flight_mode = _AUTONOMOUS_MODES.get(mode, _MANUAL)
    voltage = math.nan
    if cells:
        if not in_air:
            sag = 0.0
        voltage = cells * (_CELL_EMPTY + (_CELL_FULL - _CELL_EMPTY) * battery / 100.0 - sag)
    warning = f"battery low ({battery:.0f}% <= {warn_at:g}%)" if warn_at and battery <= warn_at else ""
    alt = v.alt
    heading = v.heading
    vn = v.vn
    ve = v.ve
    vd = v.vd
    values = {
        "connected": True,
        "link_age": 0.0,
        "lat": lat,
        "lon": lon,
        "alt": alt,
        "heading": heading,
        "vn": vn,
        "ve": ve,
        "vd": vd,
        "battery": battery,
        "armed": armed,
        "in_air": in_air,
        "autonomous": flight_mode is not _MANUAL,
        "mode": mode,
        "flight_mode": flight_mode,
        "failsafe": failsafe,
        "voltage": voltage,
        "cells": cells,
        "battery_warning": warning,
    }
    # Kept for the copies above: one of these five changed (a takeoff, a mode change: now and then).
    _keep(v, values, north, east, battery_params)
    state = _new(VehicleState)
    _set(state, "__dict__", values)
    return state


def _keep(v: Quadcopter, values: dict[str, object], north: float, east: float, params: object) -> None:
    """Keep a copy of ``values`` and what they were made of, for `snapshot`'s two copies."""
    v._snapshot_of = (
        north,
        east,
        values["alt"],
        values["heading"],
        values["vn"],
        values["ve"],
        values["vd"],
        values["armed"],
        values["in_air"],
        values["mode"],
        values["failsafe"],
        params,
        _moving(values, params),
    )
    v._snapshot = values.copy()


#: (armed, in_air, mode, failsafe, battery parameters) -> a snapshot's values with them: what a
#: moving snapshot copies, one dict for a whole swarm in flight (a thousand agents' copies of one
#: cached dict, not a thousand dicts read from memory).
_MOVING: dict[tuple[object, ...], dict[str, object]] = {}


def _moving(values: dict[str, object], params: object) -> dict[str, object]:
    key = (values["armed"], values["in_air"], values["mode"], values["failsafe"], params)
    moving = _MOVING.get(key)
    if moving is None:
        moving = values.copy()
        if len(_MOVING) < 1000:  # a few in any run: the modes, failsafes and packs of a swarm
            _MOVING[key] = moving
    return moving
