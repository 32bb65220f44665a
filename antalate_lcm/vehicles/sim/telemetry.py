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
from typing import Any

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


class _Building:
    """A `VehicleState` being filled by `snapshot`: its very slots, written as plain attributes,
    then given the class `VehicleState` (the layouts are one, so CPython allows it). The frozen
    dataclass's ``__init__`` sets each field through ``object.__setattr__``, two thirds of a
    snapshot's time, and the sim makes 20 a second per agent; the dict the sim used instead
    (``__dict__`` set whole, copied from the last still one) is gone with the slots
    (docs/simulator.md, "Issue 32, sixth pass"). Equal to ``VehicleState(**values)``:
    tests/vehicles/test_sim_snapshot.py checks it bit for bit."""

    __slots__ = VehicleState.__slots__


def snapshot(v: Quadcopter) -> VehicleState:
    """What `v`'s autopilot reports now (connected, the link fresh: `faults` ages a lost one)."""
    battery = v.battery
    cells, sag, warn_at = v._battery_params
    north = v.north
    east = v.east
    # lat/lon are recomputed only when the vehicle moved.
    if north != v._latlon_n or east != v._latlon_e:
        v._latlon_n = north
        v._latlon_e = east
        v._latlon = v.home.to_latlon(north, east)
    mode = v.mode
    flight_mode = _AUTONOMOUS_MODES.get(mode, _MANUAL)
    in_air = v.in_air
    s: Any = _Building()  # (mypy: the slots are the dataclass's fields)
    s.connected = True
    s.link_age = 0.0
    s.lat, s.lon = v._latlon
    s.alt = v.alt
    s.heading = v.heading
    s.vn = v.vn
    s.ve = v.ve
    s.vd = v.vd
    s.battery = battery
    s.armed = v.armed
    s.in_air = in_air
    s.autonomous = flight_mode is not _MANUAL
    s.mode = mode
    s.flight_mode = flight_mode
    s.failsafe = v._failsafe
    if cells:
        if not in_air:
            sag = 0.0
        s.voltage = cells * (_CELL_EMPTY + (_CELL_FULL - _CELL_EMPTY) * battery / 100.0 - sag)
    else:
        s.voltage = math.nan
    s.cells = cells
    s.battery_warning = (
        f"battery low ({battery:.0f}% <= {warn_at:g}%)" if warn_at and battery <= warn_at else ""
    )
    s.__class__ = VehicleState  # frozen from here on
    return s  # type: ignore[no-any-return]
