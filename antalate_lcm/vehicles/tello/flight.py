"""What the Tello adapter is doing: its phase and that phase's targets.

The Tello has no flight modes of its own that the SDK reports, no arming step and no return-to-home:
the phase is the adapter's, shown as the telemetry's mode. One `Flight` is shared by the HLC's calls,
the control thread and the waits of a command, always under the adapter's lock.
"""

from __future__ import annotations

import enum

from antalate_lcm.vehicles.base import FlightMode, Frame

#: A velocity set-point: vx, vy, vz, yaw_rate, frame.
Setpoint = tuple[float, float, float, float, Frame]


class TelloPhase(enum.Enum):
    """What the adapter is doing; the value is the mode name shown in telemetry."""

    GROUND = "GROUND"
    TAKEOFF = "TAKEOFF"  # the Tello's takeoff, then the climb to the target altitude
    GUIDED = "GUIDED"  # hovering or following velocity set-points
    RTL = "RTL"  # flying back to the take-off point
    LAND = "LAND"  # landing (a land command, or the end of an RTL)


FLIGHT_MODES = {TelloPhase.RTL: FlightMode.RTL, TelloPhase.LAND: FlightMode.LANDING}


class Flight:
    """The phase and its targets (the adapter's lock held for every read and write)."""

    __slots__ = (
        "climb_target",
        "failsafe",
        "land_due",
        "phase",
        "rtl_dist0",
        "rtl_start",
        "setpoint",
        "setpoint_time",
        "takeoff_point",
        "unattended_until",
    )

    def __init__(self) -> None:
        self.phase = TelloPhase.GROUND
        self.takeoff_point = (0.0, 0.0)  # metres north/east of home: the RTL's destination
        self.climb_target: float | None = None  # m; set while the rc climb is active
        self.setpoint: Setpoint | None = None
        self.setpoint_time = 0.0
        self.rtl_start = 0.0
        self.rtl_dist0 = 0.0
        self.failsafe = ""  # why the adapter is landing on its own (a failed RTL, nobody commanding)
        self.land_due: float | None = None  # clock() at which the control thread (re)tries land
        self.unattended_until: float | None = None  # after a link loss: land unless commanded by then

    def commanded(self) -> None:
        """The HLC commanded the Tello: someone is flying it after a link loss."""
        self.unattended_until = None

    def hold(self) -> None:
        """No more motion of our own: the set-point and the climb end."""
        self.setpoint = None
        self.climb_target = None

    def to_ground(self) -> None:
        self.phase = TelloPhase.GROUND
        self.hold()
        self.land_due = None
        self.unattended_until = None
