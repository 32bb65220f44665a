"""Colours by state, shared by the table, the map and the detail view so one glance means one thing.

Green = flying under autonomy, cyan = ready on the ground, yellow = in transition, magenta = coming
home, orange = a pilot has the vehicle, red = needs attention. Stale agents are drawn dim.
"""

from __future__ import annotations

from antalate_lcm.wire.vocabulary import Severity

MC_STYLE: dict[str, str] = {
    "INIT": "grey62",
    "STANDBY": "cyan",
    "TAKEOFF": "yellow",
    "MISSION": "bold green",
    "RTL": "magenta",
    "LAND": "yellow",
    "MANUAL": "dark_orange",
    "ERROR": "bold white on red",
    "HOLD": "bold yellow",  # stopped by a failsafe or the hold policy: waits for RTL/LAND
    "HLC_LOST": "bold white on red",
}

HLC_STYLE: dict[str, str] = {
    "INIT": "grey62",
    "READY": "cyan",
    "TAKEOFF": "yellow",
    "GAINING_ALTITUDE": "yellow",
    "AIRBORNE": "bold green",
    "RTL": "magenta",
    "LANDING": "yellow",
    "MANUAL": "dark_orange",
    "LOW_BATTERY": "bold red",
    "LLC_DOWN": "bold white on red",
    "HOLD": "bold yellow",
}

SEVERITY_STYLE: dict[Severity, str] = {
    Severity.INFO: "",
    Severity.WARNING: "yellow",
    Severity.ERROR: "bold red",
    Severity.CRITICAL: "bold white on red",
}

STALE_STYLE = "dim"
UNKNOWN_STYLE = "grey50"


def mc_style(state: str | None) -> str:
    return MC_STYLE.get(state or "", UNKNOWN_STYLE)


def hlc_style(state: str | None) -> str:
    return HLC_STYLE.get(state or "", UNKNOWN_STYLE)


def battery_style(battery: float) -> str:
    if battery < 0:
        return UNKNOWN_STYLE
    if battery <= 20:
        return "bold red"
    if battery <= 40:
        return "yellow"
    return "green"
