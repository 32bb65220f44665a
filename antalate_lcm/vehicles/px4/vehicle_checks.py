"""PX4's own failsafe parameters, checked before flight (pure logic; the adapter reads and writes them).

What PX4 does when antalate goes quiet is decided on the vehicle, by these parameters of PX4 v1.15.4
(src/modules/commander/commander_params.c, src/modules/navigator/navigator_params.c,
src/modules/navigator/geofence_params.c; docs/px4.md has the table):

* COM_OF_LOSS_T -- s without an OFFBOARD set-point before PX4 counts the offboard signal lost;
* COM_OBL_RC_ACT -- what it then does: 0 Position, 1 Altitude, 2 Stabilized (all need a pilot's sticks),
  3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm;
* NAV_DLL_ACT -- what it does after COM_DL_LOSS_T s without a ground station's HEARTBEAT (ours):
  0 disabled, 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Disarm;
* COM_FAIL_ACT_T -- s PX4 holds before a failsafe's action (a pilot may take over meanwhile);
* COM_LOW_BAT_ACT -- 0 warning only, 2 Land, 3 Return at critical / Land at emergency;
* GF_ACTION -- 0 none, 1 warning only, 2 Hold, 3 Return, 4 Terminate, 5 Land.

The adapter's wishes mirror what it asks of ArduCopter (`antalate_lcm.vehicles.mavlink.vehicle_checks`):
a stream that stops (a link cut, a dead HLC) makes PX4 **hold** where it is (as ArduCopter's GUIDED holds
after GUID_TIMEOUT), and antalate gone for COM_DL_LOSS_T brings it **home** (as FS_GCS_ENABLE = RTL).
"""

from __future__ import annotations

from collections.abc import Mapping

from antalate_lcm.vehicles.mavlink.vehicle_checks import Finding, Rule, above, findings, one_of

READ = (
    "COM_OF_LOSS_T",
    "COM_OBL_RC_ACT",
    "NAV_DLL_ACT",
    "COM_DL_LOSS_T",
    "COM_FAIL_ACT_T",
    "COM_LOW_BAT_ACT",
    "GF_ACTION",
)
REQUIRED_GROUPS: tuple[tuple[str, ...], ...] = tuple((n,) for n in READ)

OBL_HOLD = 5  # COM_OBL_RC_ACT: Hold
OBL_NEEDS_PILOT = frozenset({0, 1, 2})  # Position, Altitude, Stabilized: nothing to fly them without sticks
DLL_RETURN = 2  # NAV_DLL_ACT: Return
LOW_BAT_RETURN = 3  # COM_LOW_BAT_ACT: Return at critical, Land at emergency
GF_RETURN = 3  # GF_ACTION: Return


def check(values: Mapping[str, float], *, max_offboard_loss_timeout: float) -> list[Finding]:
    """Every finding for the PX4 parameter `values` (empty: PX4's failsafes protect the vehicle)."""
    rules = (
        Rule(
            "COM_OF_LOSS_T",
            above(max_offboard_loss_timeout),
            max_offboard_loss_timeout,
            lambda loss_t: f"a silent antalate's last set-point is flown for {loss_t:g} s",
        ),
        Rule(
            "COM_OBL_RC_ACT",
            one_of(*OBL_NEEDS_PILOT),
            OBL_HOLD,
            "offboard loss hands over to a pilot's sticks (Position/Altitude/Stabilized)",
        ),
        Rule(
            "NAV_DLL_ACT",
            one_of(0),
            DLL_RETURN,
            "data link loss off: if antalate dies in flight PX4 holds until its battery fails",
        ),
        Rule("COM_LOW_BAT_ACT", one_of(0), LOW_BAT_RETURN, "a low battery is only a warning"),
        Rule("GF_ACTION", one_of(0, 1), GF_RETURN, "a geofence breach is only reported"),
    )
    return findings(rules, values, unread=READ)
