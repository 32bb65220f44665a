"""The events of the HLC table (`HlcEvent`, docs/design.md §6) and what one autopilot snapshot says
of who flies the vehicle (`classify`, `pilot_in_control`): how :mod:`antalate_lcm.agent.hlc.machine`
turns its inputs into events is described there. Pure."""

from __future__ import annotations

import enum

from antalate_lcm.vehicles.base import FlightMode, VehicleState


class HlcEvent(enum.Enum):
    """Inputs of the table, derived from observations (see the module docstring)."""

    # Members are singletons compared by identity: identity's hash (in C) instead of Enum's, which
    # hashes the name in Python on every table lookup (several per control tick per agent).
    __hash__ = object.__hash__

    LINK_UP = "LINK_UP"  # INIT: autopilot connected, link fresh, MC heard, vehicle on the ground
    RESYNC_AIRBORNE = "RESYNC_AIRBORNE"  # INIT: armed and in air, autopilot in GUIDED
    RESYNC_LANDING = "RESYNC_LANDING"  # INIT: armed and in air, autopilot landing
    RESYNC_RTL = "RESYNC_RTL"  # INIT: armed and in air, autopilot returning
    RESYNC_MANUAL = "RESYNC_MANUAL"  # INIT: armed and in air, a pilot in control
    MC_TAKEOFF = "MC_TAKEOFF"  # MC changed to TAKEOFF (edge)
    MC_LAND = "MC_LAND"  # MC is in LAND (level)
    MC_RTL = "MC_RTL"  # MC is in RTL (level)
    ARMED = "ARMED"  # result of Action.ARM
    ARM_FAILED = "ARM_FAILED"  # result of Action.ARM
    TAKEOFF_FAILED = "TAKEOFF_FAILED"  # result of Action.TAKEOFF
    ALTITUDE_REACHED = "ALTITUDE_REACHED"
    GAIN_ALTITUDE_TIMEOUT = "GAIN_ALTITUDE_TIMEOUT"
    LANDED = "LANDED"  # on the ground and disarmed
    PILOT_TAKEOVER = "PILOT_TAKEOVER"  # armed and no longer under computer control
    LOW_BATTERY = "LOW_BATTERY"
    LINK_LOST = "LINK_LOST"  # link_age >= link_timeout
    AUTOPILOT_LAND = "AUTOPILOT_LAND"  # the autopilot reports it is landing on its own
    AUTOPILOT_RTL = "AUTOPILOT_RTL"  # the autopilot reports it is returning on its own
    RESYNC_HOLD = "RESYNC_HOLD"  # INIT: armed and in air, autopilot holding on a failsafe
    MC_HOLD = "MC_HOLD"  # MC is in HOLD (level)
    FAILSAFE_RTL = "FAILSAFE_RTL"  # VehicleState.failsafe set, flight_mode RTL
    FAILSAFE_LAND = "FAILSAFE_LAND"  # VehicleState.failsafe set, flight_mode LANDING
    FAILSAFE_HOLD = "FAILSAFE_HOLD"  # VehicleState.failsafe set, flight_mode HOLD
    LINK_REGAINED_GROUND = "LINK_REGAINED_GROUND"  # LLC_DOWN: fresh again, vehicle on the ground
    LINK_REGAINED_GUIDED = "LINK_REGAINED_GUIDED"  # LLC_DOWN: fresh again, flying in GUIDED
    LINK_REGAINED_RTL = "LINK_REGAINED_RTL"  # LLC_DOWN: fresh again, autopilot returning
    LINK_REGAINED_LANDING = "LINK_REGAINED_LANDING"  # LLC_DOWN: fresh again, autopilot landing
    LINK_REGAINED_HOLD = "LINK_REGAINED_HOLD"  # LLC_DOWN: fresh again, autopilot holding on a failsafe
    LINK_REGAINED_MANUAL = "LINK_REGAINED_MANUAL"  # LLC_DOWN: fresh again, a pilot in control


class Control(enum.Enum):
    """Who flies the vehicle and how, read from one snapshot (`classify`)."""

    GROUND = "GROUND"  # not (armed and in the air)
    GUIDED = "GUIDED"  # flying under our commands
    RTL = "RTL"  # the autopilot returns on its own (failsafe or not)
    LANDING = "LANDING"  # the autopilot lands on its own
    HOLD = "HOLD"  # the autopilot holds position on a failsafe (fence BRAKE)
    PILOT = "PILOT"  # a human pilot


#: The modes an autopilot failsafe flies the vehicle in (never a pilot's, see `pilot_in_control`).
FAILSAFE_MODES = (FlightMode.RTL, FlightMode.LANDING, FlightMode.HOLD)


def pilot_in_control(ap: VehicleState) -> bool:
    """A human pilot has the vehicle: not autonomous, or a pilot's mode, unless a failsafe explains it.

    An autopilot failsafe (`VehicleState.failsafe` with RTL, LANDING or HOLD) is the autopilot's
    own decision, never a pilot's, even when the adapter says the vehicle left our control. HOLD
    without a failsafe is a pilot's BRAKE.
    """
    if ap.failsafe and ap.flight_mode in FAILSAFE_MODES:
        return False
    return not ap.autonomous or ap.flight_mode in (FlightMode.MANUAL, FlightMode.HOLD)


def classify(ap: VehicleState) -> Control:
    """What the vehicle is doing, for the resync rows (INIT, and LLC_DOWN when the link is back)."""
    if not (ap.armed and ap.in_air):
        return Control.GROUND
    if pilot_in_control(ap):
        return Control.PILOT
    return {
        FlightMode.RTL: Control.RTL,
        FlightMode.LANDING: Control.LANDING,
        FlightMode.HOLD: Control.HOLD,
    }.get(ap.flight_mode, Control.GUIDED)  # type: ignore[arg-type]


__all__ = ["FAILSAFE_MODES", "Control", "HlcEvent", "classify", "pilot_in_control"]
