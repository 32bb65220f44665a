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
    # lat/lon are recomputed only when the vehicle moved. The state is built without the frozen
    # dataclass's ``__init__``: its per-field ``object.__setattr__`` took two thirds of a snapshot,
    # and the sim makes 20 a second per agent; the fresh dict below becomes the instance's own
    # (copying it in took half the rest). Equal to ``VehicleState(**values)``
    # (tests/vehicles/test_sim_adapter.py checks it).
    ne = (v.north, v.east)
    if ne != v._latlon_of:
        v._latlon_of = ne
        v._latlon = v.home.to_latlon(v.north, v.east)
    lat, lon = v._latlon
    mode = v.mode
    flight_mode = _AUTONOMOUS_MODES.get(mode, _MANUAL)
    cells, sag, warn_at = v._battery_params
    battery = v.battery
    voltage = math.nan
    if cells:
        if not v.in_air:
            sag = 0.0
        voltage = cells * (_CELL_EMPTY + (_CELL_FULL - _CELL_EMPTY) * battery / 100.0 - sag)
    warning = f"battery low ({battery:.0f}% <= {warn_at:g}%)" if warn_at and battery <= warn_at else ""
    state = _new(VehicleState)
    _set(
        state,
        "__dict__",
        {
            "connected": True,
            "link_age": 0.0,
            "lat": lat,
            "lon": lon,
            "alt": v.alt,
            "heading": v.heading,
            "vn": v.vn,
            "ve": v.ve,
            "vd": v.vd,
            "battery": battery,
            "armed": v.armed,
            "in_air": v.in_air,
            "autonomous": flight_mode is not _MANUAL,
            "mode": mode,
            "flight_mode": flight_mode,
            "failsafe": v._failsafe,
            "voltage": voltage,
            "cells": cells,
            "battery_warning": warning,
        },
    )
    return state
