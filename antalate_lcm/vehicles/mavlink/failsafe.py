"""Who changed the flight mode: a pilot, or one of ArduCopter's own failsafes (pure logic, no I/O).

ArduCopter's fence, battery, EKF and GCS failsafes switch the mode (RTL, LAND, BRAKE, ALT_HOLD) exactly as a
pilot's mode switch does; the HEARTBEAT alone cannot tell them apart. Taking a fence breach for a pilot
makes the HLC stand down (MANUAL) while the autopilot is in fact flying home on its own. So the adapter
collects what ArduPilot reports besides the mode -- SYS_STATUS health bits (GEOFENCE, BATTERY, AHRS),
FENCE_STATUS ``breach_status``, BATTERY_STATUS ``charge_state``, and STATUSTEXT lines -- and attributes a
mode change the adapter did not command to the failsafe active around it (`FailsafeTracker`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from antalate_lcm.vehicles.base import FlightMode

FENCE = "fence breach"
BATTERY = "battery failsafe"
EKF = "EKF failsafe"
GCS = "GCS failsafe"
RC = "RC failsafe"
#: Reported first when several are active at once: the one the operator must act on first.
PRIORITY = (FENCE, BATTERY, EKF, GCS, RC)

#: ArduCopter modes a failsafe can choose (FENCE_ACTION, BATT_FS_*_ACT, FS_EKF_ACTION, FS_GCS_ENABLE,
#: FS_THR_ENABLE).
FAILSAFE_MODES = frozenset({"RTL", "SMART_RTL", "AUTO_RTL", "LAND", "BRAKE", "ALT_HOLD"})

#: How each ArduCopter mode is classified for the HLC when nobody's failsafe explains it.
FLIGHT_MODES: dict[str, FlightMode] = {
    "GUIDED": FlightMode.GUIDED,
    "LAND": FlightMode.LANDING,
    "RTL": FlightMode.RTL,
    "SMART_RTL": FlightMode.RTL,
    "AUTO_RTL": FlightMode.RTL,
}

#: A mode change counts as a failsafe's when its evidence is at most this old (or arrives this soon after):
#: ArduPilot sends the STATUSTEXT at once, the HEARTBEAT with the new mode up to a second later, and
#: FENCE_STATUS / BATTERY_STATUS at their stream rate.
ATTRIBUTION_WINDOW = 5.0

# STATUSTEXT lines ArduPilot sends when a failsafe fires, as ArduCopter 4.6.3 SITL says them: AP_BattMonitor
# "Battery 1 is low 10.80V used 401 mAh" then events.cpp "Battery Failsafe"; "GCS Failsafe"; ekf_check.cpp
# "EKF variance", "EKF Failsafe: changed to LAND Mode"; AC_Fence "Circle fence breached"; events.cpp
# failsafe_radio_on_event "Radio Failsafe" (or "Radio Failsafe - Continuing Landing" ...); and the lines
# that clear them ("Radio Failsafe Cleared", "EKF Failsafe Cleared", "Fence breach cleared").
_TEXTS: tuple[tuple[re.Pattern[str], str], ...] = (
    (re.compile(r"fence.*breach|breach.*fence", re.I), FENCE),
    (re.compile(r"\bbattery\b.*\b(low|critical|failsafe)\b|\bbatt(ery)? failsafe", re.I), BATTERY),
    (re.compile(r"\bEKF (failsafe|variance)", re.I), EKF),
    (re.compile(r"\bGCS failsafe\b", re.I), GCS),
    (re.compile(r"\bradio failsafe\b", re.I), RC),
)
_CLEARED = re.compile(r"failsafe cleared|cleared.*failsafe|breach cleared", re.I)
_BATTERY_LEVEL = re.compile(r"\bbattery\b.*\b(low|critical)\b", re.I)


def text_failsafe(text: str) -> str:
    """The failsafe a STATUSTEXT announces ("" for anything else, including "... Failsafe Cleared")."""
    if _CLEARED.search(text):
        return ""
    return next((reason for pattern, reason in _TEXTS if pattern.search(text)), "")


def text_battery_level(text: str) -> str:
    """ "low" / "critical" from ArduPilot's battery failsafe STATUSTEXT, "" otherwise."""
    match = _BATTERY_LEVEL.search(text)
    return match.group(1).lower() if match else ""


@dataclass
class FailsafeTracker:
    """Evidence of the autopilot's failsafes over time, and the reason latched for the current mode.

    `active` failsafes are levels (FENCE_STATUS breach, BATTERY_STATUS charge_state, a SYS_STATUS health bit
    dropping); `event` failsafes are STATUSTEXT lines, remembered for `ATTRIBUTION_WINDOW`. A mode the adapter
    did not command gets the failsafe that explains it, and keeps it while the vehicle stays in that mode
    (the fence breach clears as RTL flies back inside, but the RTL is still the fence's).
    """

    active: set[str] = field(default_factory=set)
    events: dict[str, float] = field(default_factory=dict)  # reason -> clock time last announced
    mode: str = ""
    mode_since: float = 0.0
    commanded: bool = False
    reason: str = ""

    def set_active(self, reason: str, on: bool, now: float) -> None:
        if on:
            if reason not in self.active:
                self.events[reason] = now
            self.active.add(reason)
            self._attribute(now)
        else:
            self.active.discard(reason)

    def event(self, reason: str, now: float) -> None:
        if reason:
            self.events[reason] = now
            self._attribute(now)

    def on_mode(self, mode: str, now: float, *, commanded: bool) -> None:
        """A HEARTBEAT showed `mode`; `commanded` when the adapter itself asked for it."""
        if mode == self.mode:
            return
        self.mode, self.mode_since, self.commanded, self.reason = mode, now, commanded, ""
        self._attribute(now)

    def _attribute(self, now: float) -> None:
        if self.reason or self.commanded or self.mode not in FAILSAFE_MODES:
            return
        if now - self.mode_since > ATTRIBUTION_WINDOW:
            return  # the mode is long established: this failsafe did not choose it
        recent = {r for r, t in self.events.items() if abs(t - self.mode_since) <= ATTRIBUTION_WINDOW}
        candidates = self.active | recent
        self.reason = next((r for r in PRIORITY if r in candidates), "")


def classify(mode: str, reason: str) -> tuple[FlightMode, bool, str]:
    """(flight_mode, autonomous, failsafe) for ArduCopter `mode` and the failsafe latched for it.

    BRAKE is a pilot's hold unless a failsafe chose it (FENCE_ACTION 4, "Brake or Land"): then it is the
    autopilot holding position, `FlightMode.HOLD`. ALT_HOLD from an EKF failsafe (FS_EKF_ACTION 2) needs
    a pilot: MANUAL, but the failsafe is named.
    """
    if mode == "BRAKE" and reason:
        return FlightMode.HOLD, True, reason
    flight_mode = FLIGHT_MODES.get(mode, FlightMode.MANUAL)
    if flight_mode is FlightMode.GUIDED:
        return flight_mode, True, ""
    return flight_mode, flight_mode is not FlightMode.MANUAL, reason
