"""What the Crazyflie adapter is doing, and the flight mode and mode name the HLC sees for it (pure).

The adapter has no autopilot modes to read back: under the high-level commander the firmware flies
trajectories, and a velocity stream is the commander's generic set-points. So the adapter's own state
(`control`) is the mode, and these tables translate it for `VehicleState`.
"""

from __future__ import annotations

from antalate_lcm.vehicles.base import FlightMode

__all__ = ["FLIGHT_MODES", "HOLD", "IDLE", "LAND", "MODE_NAMES", "RTL_GO", "RTL_LAND", "STREAM", "TAKEOFF"]

# What the adapter is doing; the flight mode the HLC sees follows from it.
IDLE, TAKEOFF, HOLD, STREAM, LAND, RTL_GO, RTL_LAND = (
    "IDLE",
    "TAKEOFF",
    "HOLD",
    "STREAM",
    "LAND",
    "RTL",
    "RTL_LAND",
)
#: The flight mode the HLC sees (`VehicleState.flight_mode`).
FLIGHT_MODES = {
    IDLE: FlightMode.GUIDED,
    TAKEOFF: FlightMode.GUIDED,
    HOLD: FlightMode.GUIDED,
    STREAM: FlightMode.GUIDED,
    LAND: FlightMode.LANDING,
    RTL_GO: FlightMode.RTL,
    RTL_LAND: FlightMode.RTL,
}
#: The mode name the HLC sees (`VehicleState.mode`; "LOCKED" overrides it while the supervisor is locked).
MODE_NAMES = {
    IDLE: "IDLE",
    TAKEOFF: "TAKEOFF",
    HOLD: "HL_HOLD",
    STREAM: "VELOCITY",
    LAND: "LAND",
    RTL_GO: "RTL",
    RTL_LAND: "RTL_LAND",
}
