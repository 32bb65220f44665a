"""PX4's flight modes as HEARTBEAT ``custom_mode`` carries them, and what each means to the HLC (pure).

PX4 packs its mode into ``custom_mode`` as ``main_mode << 16 | sub_mode << 24``
(``union px4_custom_mode`` in PX4 v1.15.4 src/modules/commander/px4_custom_mode.h; the HEARTBEAT stream,
src/modules/mavlink/streams/HEARTBEAT.hpp, sends ``get_px4_custom_mode(nav_state)``). The same pair is
what MAV_CMD_DO_SET_MODE takes as param2 (main) and param3 (sub)
(src/modules/mavlink/mavlink_receiver.cpp, ``handle_message_set_mode`` / commander's
``handle_command`` for VEHICLE_CMD_DO_SET_MODE). Names follow QGroundControl's and pymavlink's
``AUTO.LOITER`` style so an operator sees what a ground station would show.
"""

from __future__ import annotations

from antalate_lcm.vehicles.base import FlightMode

# Main modes (px4_custom_mode.h, PX4_CUSTOM_MAIN_MODE_*).
MANUAL = 1
ALTCTL = 2
POSCTL = 3
AUTO = 4
ACRO = 5
OFFBOARD = 6
STABILIZED = 7
RATTITUDE = 8
TERMINATION = 9

# AUTO sub modes (PX4_CUSTOM_SUB_MODE_AUTO_*).
AUTO_READY = 1
AUTO_TAKEOFF = 2
AUTO_LOITER = 3
AUTO_MISSION = 4
AUTO_RTL = 5
AUTO_LAND = 6
AUTO_FOLLOW_TARGET = 8
AUTO_PRECLAND = 9
AUTO_VTOL_TAKEOFF = 10

_MAIN_NAMES = {
    MANUAL: "MANUAL",
    ALTCTL: "ALTCTL",
    POSCTL: "POSCTL",
    ACRO: "ACRO",
    OFFBOARD: "OFFBOARD",
    STABILIZED: "STABILIZED",
    RATTITUDE: "RATTITUDE",
    TERMINATION: "TERMINATION",
}
_AUTO_NAMES = {
    AUTO_READY: "AUTO.READY",
    AUTO_TAKEOFF: "AUTO.TAKEOFF",
    AUTO_LOITER: "AUTO.LOITER",
    AUTO_MISSION: "AUTO.MISSION",
    AUTO_RTL: "AUTO.RTL",
    AUTO_LAND: "AUTO.LAND",
    AUTO_FOLLOW_TARGET: "AUTO.FOLLOW_TARGET",
    AUTO_PRECLAND: "AUTO.PRECLAND",
    AUTO_VTOL_TAKEOFF: "AUTO.VTOL_TAKEOFF",
}

#: The modes the adapter commands, by name: (main, sub) for MAV_CMD_DO_SET_MODE.
COMMANDS: dict[str, tuple[int, int]] = {
    "OFFBOARD": (OFFBOARD, 0),
    "AUTO.LOITER": (AUTO, AUTO_LOITER),
    "AUTO.RTL": (AUTO, AUTO_RTL),
    "AUTO.LAND": (AUTO, AUTO_LAND),
}

#: Hold ("Hold" in QGroundControl): the mode a PX4 failsafe's delay (COM_FAIL_ACT_T) and a Hold action use.
HOLD = "AUTO.LOITER"
#: Modes in which PX4 flies on its own logic towards the ground or home.
RTL_MODES = frozenset({"AUTO.RTL"})
LAND_MODES = frozenset({"AUTO.LAND", "AUTO.PRECLAND"})
#: Modes only the adapter's own commands lead to (with our NAV_TAKEOFF or our OFFBOARD switch).
GUIDED_MODES = frozenset({"OFFBOARD", "AUTO.TAKEOFF"})
#: Modes an adapter that starts with PX4 already flying takes as its own (an HLC restarted in flight):
#: PX4 hovers in Hold after our take-off and when our set-points stop, and OFFBOARD is a companion's. PX4
#: does not say who asked for a Hold, so a pilot's Hold found at start is taken too -- the pilot's next
#: mode change is still seen as a takeover.
RESYNC_MODES = frozenset({"OFFBOARD", HOLD})


def split(custom_mode: int) -> tuple[int, int]:
    """(main, sub) of a HEARTBEAT ``custom_mode``."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def pack(main: int, sub: int) -> int:
    """The ``custom_mode`` a HEARTBEAT shows for (main, sub)."""
    return (main & 0xFF) << 16 | (sub & 0xFF) << 24


def mode_name(custom_mode: int) -> str:
    """PX4's name for a HEARTBEAT ``custom_mode`` (``MODE_<main>.<sub>`` for one not in the tables)."""
    main, sub = split(custom_mode)
    if main == AUTO:
        return _AUTO_NAMES.get(sub, f"AUTO.{sub}")
    if main == POSCTL and sub:
        return {1: "POSCTL.ORBIT", 2: "POSCTL.SLOW"}.get(sub, f"POSCTL.{sub}")
    return _MAIN_NAMES.get(main, f"MODE_{main}.{sub}")


def classify(mode: str, *, ours: bool, failsafe: str) -> tuple[FlightMode, bool, str]:
    """(flight_mode, autonomous, failsafe) for PX4 `mode`.

    `ours`: the adapter's commands led to it (our NAV_TAKEOFF, the Hold PX4 enters when that take-off
    ends, our OFFBOARD switch, our Hold). `failsafe`: the reason PX4's failsafe state machine switched
    (empty: none). A Hold that is neither ours nor a failsafe's is a pilot's or another ground station's
    (`FlightMode.MANUAL`), exactly as ArduCopter's BRAKE; RTL and LAND are the autopilot's whoever chose
    them, as for ArduCopter. Any other mode (POSCTL, ALTCTL, AUTO.MISSION, ...) is a person's.
    """
    if mode in RTL_MODES:
        return FlightMode.RTL, True, failsafe
    if mode in LAND_MODES:
        return FlightMode.LANDING, True, failsafe
    if mode == HOLD:
        if failsafe:
            return FlightMode.HOLD, True, failsafe
        if ours:
            return FlightMode.GUIDED, True, ""
        return FlightMode.MANUAL, False, ""
    if mode in GUIDED_MODES and ours:
        return FlightMode.GUIDED, True, ""
    return FlightMode.MANUAL, False, failsafe
