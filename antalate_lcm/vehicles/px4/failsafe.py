"""Which of PX4's failsafes switched the mode (pure logic, no I/O).

PX4 v1.15.4 says *that* a failsafe is active, not which one: its HEARTBEAT ``system_status`` turns
MAV_STATE_CRITICAL while armed and ``vehicle_status.failsafe`` is set (src/modules/mavlink/streams/
HEARTBEAT.hpp), and the failsafe framework announces "Failsafe activated" as a STATUSTEXT; the detailed
reason travels only in the MAVLink events protocol (src/modules/commander/failsafe/framework.cpp,
``notifyUser``). So the reason is read off the rest of the telemetry, in the same words as ArduCopter's
(`antalate_lcm.vehicles.mavlink.failsafe`), so the HLC and the operator see one vocabulary:

* the battery: BATTERY_STATUS ``charge_state`` LOW or worse, or SYS_STATUS's battery health bit down
  (COM_LOW_BAT_ACT);
* the geofence: SYS_STATUS's GEOFENCE health bit down or a geofence STATUSTEXT (GF_ACTION);
* the data link: no GCS HEARTBEAT at the vehicle for COM_DL_LOSS_T (NAV_DLL_ACT) -- antalate's own
  link was stale for at least that long, or PX4 said so;
* the offboard signal: the vehicle left OFFBOARD (COM_OF_LOSS_T, then COM_OBL_RC_ACT).
"""

from __future__ import annotations

import re

from antalate_lcm.vehicles.mavlink.failsafe import BATTERY, FENCE, GCS

#: PX4's own: the OFFBOARD set-point stream stopped for COM_OF_LOSS_T (ArduCopter has no such failsafe).
OFFBOARD_LOSS = "offboard loss"
#: Named when PX4 reports a failsafe and nothing else explains it.
UNKNOWN = "PX4 failsafe"

#: Reported first when several are active at once, as ArduCopter's PRIORITY.
PRIORITY = (FENCE, BATTERY, GCS, OFFBOARD_LOSS)

_FENCE_TEXT = re.compile(r"geofence", re.I)
_LINK_TEXT = re.compile(r"(data ?link|connection to (the )?(gcs|ground station)).*lost", re.I)


def text_evidence(text: str) -> str:
    """The failsafe a PX4 STATUSTEXT points at ("" for anything else)."""
    if _FENCE_TEXT.search(text):
        return FENCE
    if _LINK_TEXT.search(text):
        return GCS
    return ""


def reason(
    *,
    left_offboard: bool,
    battery: bool,
    fence: bool,
    link_lost: bool,
) -> str:
    """The failsafe that best explains a mode change PX4 made with its failsafe flag set."""
    evidence = {FENCE: fence, BATTERY: battery, GCS: link_lost, OFFBOARD_LOSS: left_offboard}
    return next((r for r in PRIORITY if evidence[r]), UNKNOWN)
