"""The set-point the shipped behaviors publish on VELOCITY_CMD: horizontal (vz = 0: the HLC holds the
takeoff altitude), in the NED frame (the swarm rules, direction_follow) or the body frame with a yaw
rate (dovrat_swarm). Not a behavior: the one place they build the message."""

from __future__ import annotations

from antalate_lcm.msgs import velocity_cmd_t


def velocity_cmd(
    vx: float, vy: float, *, frame: int = velocity_cmd_t.NED, yaw_rate: float = 0.0
) -> velocity_cmd_t:
    """``vx``, ``vy`` m/s (north/east in NED, forward/right in BODY) and ``yaw_rate`` deg/s, altitude held."""
    msg = velocity_cmd_t()
    msg.frame = frame
    msg.vx, msg.vy, msg.vz, msg.yaw_rate = vx, vy, 0.0, yaw_rate
    return msg
