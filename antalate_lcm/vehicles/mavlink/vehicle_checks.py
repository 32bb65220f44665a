"""The vehicle's own failsafes, checked before flight (pure logic; the adapter reads and writes the parameters).

If the HLC process dies mid-flight, nothing of antalate can save the copter: ArduCopter must. It keeps the
last velocity target for ``GUID_TIMEOUT`` seconds, then stops and hovers; whether it then comes home
depends on its GCS failsafe, which only watches HEARTBEATs from ``SYSID_MYGCS`` -- and the adapter sends as
245 while ArduPilot's default is 255. These checks name every such parameter that leaves the vehicle
unprotected, with the value to set. Meanings and defaults are ArduCopter 4.x's (ArduCopter/Parameters.cpp,
libraries/AC_Fence, libraries/AP_BattMonitor); see docs/ardupilot.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

#: Copter 4.7 renamed SYSID_MYGCS to MAV_GCS_SYSID; whichever the vehicle has is checked.
GCS_SYSID_NAMES = ("SYSID_MYGCS", "MAV_GCS_SYSID")

#: Parameters read on connect. GUID_TIMEOUT and FS_GCS_TIMEOUT exist from Copter 4.1 (3 s and 5 s fixed before).
READ = (
    "FS_GCS_ENABLE",
    "FS_GCS_TIMEOUT",
    *GCS_SYSID_NAMES,
    "GUID_TIMEOUT",
    "FENCE_ENABLE",
    "FENCE_ACTION",
    "BATT_MONITOR",
    "BATT_FS_LOW_ACT",
    "BATT_LOW_VOLT",
)
_OPTIONAL = frozenset({"FS_GCS_TIMEOUT", "GUID_TIMEOUT", *GCS_SYSID_NAMES})
#: A read is complete when one name of each group arrived (the optional ones come in the same burst).
REQUIRED_GROUPS: tuple[tuple[str, ...], ...] = (
    *((n,) for n in READ if n not in _OPTIONAL),
    GCS_SYSID_NAMES,
)

#: Volts per cell for BATT_LOW_VOLT when the adapter sets it: below the HLC's `low_cell_voltage` (3.5 V),
#: so antalate's own RTL comes first and ArduPilot's failsafe is the backstop.
LOW_VOLT_PER_CELL = 3.4

FS_GCS_RTL = (
    1  # FS_GCS_ENABLE: 0 disabled, 1 RTL, 3 SmartRTL or RTL, 4 SmartRTL or Land, 5 Land, 6, 7 Brake or Land
)
FENCE_RTL_OR_LAND = 1  # FENCE_ACTION: 0 report only, 1 RTL or Land, 2 Land, 3 SmartRTL.., 4 Brake or Land, 5
BATT_FS_RTL = 2  # BATT_FS_LOW_ACT: 0 none, 1 Land, 2 RTL, 3 SmartRTL or RTL, 4 SmartRTL or Land, 5 Terminate


@dataclass(frozen=True)
class Finding:
    """One parameter that leaves the vehicle unprotected; `want` is None when only a person can fix it."""

    param: str
    value: float | None  # None: the vehicle did not report it
    want: float | None
    why: str

    @property
    def settable(self) -> bool:
        return self.want is not None and self.value is not None

    def text(self) -> str:
        shown = "not reported" if self.value is None else f"= {self.value:g}"
        fix = f"set {self.param} = {self.want:g}" if self.want is not None else "configure it on the vehicle"
        return f"{self.param} {shown} ({self.why}): {fix}"


NOT_READ = "not read from the vehicle"


@dataclass(frozen=True)
class Rule:
    """A parameter whose value can leave the vehicle unprotected (ArduCopter's here, PX4's in `px4`).

    `bad` says which values do, `want` is the value to set instead (None: only a person can choose),
    `why` the reason shown (given the value when it names it). A `required` parameter the vehicle did
    not report is a finding too; any other is left alone (an older firmware may lack it).
    """

    param: str
    bad: Callable[[float], bool]
    want: float | None
    why: str | Callable[[float], str]
    required: bool = False

    def finding(self, values: Mapping[str, float]) -> Finding | None:
        value = values.get(self.param)
        if value is None or not math.isfinite(value):
            return Finding(self.param, None, None, NOT_READ) if self.required else None
        if not self.bad(float(value)):
            return None
        why = self.why if isinstance(self.why, str) else self.why(float(value))
        return Finding(self.param, float(value), self.want, why)


def one_of(*codes: int) -> Callable[[float], bool]:
    """`Rule.bad` for an enumerated parameter: its value rounds to one of `codes`."""
    return lambda value: round(value) in codes


def above(limit: float) -> Callable[[float], bool]:
    """`Rule.bad` for a timeout: longer than `limit` (by more than a float's rounding)."""
    return lambda value: value > limit + 1e-6


def findings(rules: Iterable[Rule], values: Mapping[str, float], unread: Iterable[str] = ()) -> list[Finding]:
    """`unread` parameters missing from `values` first, then what each of `rules` finds, in order."""
    found = [Finding(n, None, None, NOT_READ) for n in unread if n not in values]
    return found + [f for rule in rules if (f := rule.finding(values)) is not None]


def gcs_sysid_name(values: Mapping[str, float]) -> str:
    """The name this firmware uses for the GCS system id (SYSID_MYGCS unless only MAV_GCS_SYSID was read)."""
    return next((n for n in GCS_SYSID_NAMES if n in values), GCS_SYSID_NAMES[0])


def check(
    values: Mapping[str, float], *, source_system: int, max_guid_timeout: float, cells: int
) -> list[Finding]:
    """Every finding for the parameter `values` read from the vehicle (empty: its failsafes protect it)."""
    low_volt = round(LOW_VOLT_PER_CELL * cells, 2) if cells > 0 else None
    cells_hint = "" if cells > 0 else " (set the adapter's `cells` to let it choose)"
    rules = (
        Rule(
            "FS_GCS_ENABLE",
            one_of(0),
            FS_GCS_RTL,
            "GCS failsafe off: if antalate dies in flight the copter hovers until its battery fails",
        ),
        Rule(
            gcs_sysid_name(values),
            lambda sysid: round(sysid) != source_system,
            source_system,
            lambda sysid: f"the GCS failsafe watches system {sysid:g}, antalate sends as {source_system}",
            required=True,
        ),
        Rule(
            "GUID_TIMEOUT",
            above(max_guid_timeout),
            max_guid_timeout,
            lambda guid: f"a dead HLC's last velocity is flown for {guid:g} s",
        ),
        Rule("FENCE_ENABLE", one_of(0), 1, "no geofence"),
        Rule("FENCE_ACTION", one_of(0), FENCE_RTL_OR_LAND, "a fence breach is only reported"),
        Rule("BATT_MONITOR", one_of(0), None, "no battery monitor: no battery failsafe"),
        Rule("BATT_FS_LOW_ACT", one_of(0), BATT_FS_RTL, "a low battery does nothing"),
        Rule("BATT_LOW_VOLT", lambda volts: volts <= 0.0, low_volt, "no low-voltage failsafe" + cells_hint),
    )
    return findings(rules, values, unread=[n for n in READ if n not in _OPTIONAL])
