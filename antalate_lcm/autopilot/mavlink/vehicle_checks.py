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
from collections.abc import Mapping
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


def gcs_sysid_name(values: Mapping[str, float]) -> str:
    """The name this firmware uses for the GCS system id (SYSID_MYGCS unless only MAV_GCS_SYSID was read)."""
    return next((n for n in GCS_SYSID_NAMES if n in values), GCS_SYSID_NAMES[0])


def check(
    values: Mapping[str, float], *, source_system: int, max_guid_timeout: float, cells: int
) -> list[Finding]:
    """Every finding for the parameter `values` read from the vehicle (empty: its failsafes protect it)."""
    findings: list[Finding] = []
    missing = [n for n in READ if n not in values and n not in _OPTIONAL]
    findings += [Finding(n, None, None, "not read from the vehicle") for n in missing]

    def get(name: str) -> float | None:
        value = values.get(name)
        return None if value is None or not math.isfinite(value) else float(value)

    fs_gcs = get("FS_GCS_ENABLE")
    if fs_gcs is not None and round(fs_gcs) == 0:
        findings.append(
            Finding(
                "FS_GCS_ENABLE",
                fs_gcs,
                FS_GCS_RTL,
                "GCS failsafe off: if antalate dies in flight the copter hovers until its battery fails",
            )
        )
    sysid_name = gcs_sysid_name(values)
    sysid = get(sysid_name)
    if sysid is None:
        findings.append(Finding(sysid_name, None, None, "not read from the vehicle"))
    elif round(sysid) != source_system:
        findings.append(
            Finding(
                sysid_name,
                sysid,
                source_system,
                f"the GCS failsafe watches system {sysid:g}, antalate sends as {source_system}",
            )
        )
    guid = get("GUID_TIMEOUT")
    if guid is not None and guid > max_guid_timeout + 1e-6:
        findings.append(
            Finding(
                "GUID_TIMEOUT", guid, max_guid_timeout, f"a dead HLC's last velocity is flown for {guid:g} s"
            )
        )
    fence = get("FENCE_ENABLE")
    if fence is not None and round(fence) == 0:
        findings.append(Finding("FENCE_ENABLE", fence, 1, "no geofence"))
    action = get("FENCE_ACTION")
    if action is not None and round(action) == 0:
        findings.append(Finding("FENCE_ACTION", action, FENCE_RTL_OR_LAND, "a fence breach is only reported"))
    monitor = get("BATT_MONITOR")
    if monitor is not None and round(monitor) == 0:
        findings.append(Finding("BATT_MONITOR", monitor, None, "no battery monitor: no battery failsafe"))
    low_act = get("BATT_FS_LOW_ACT")
    if low_act is not None and round(low_act) == 0:
        findings.append(Finding("BATT_FS_LOW_ACT", low_act, BATT_FS_RTL, "a low battery does nothing"))
    low_volt = get("BATT_LOW_VOLT")
    if low_volt is not None and low_volt <= 0.0:
        want = round(LOW_VOLT_PER_CELL * cells, 2) if cells > 0 else None
        findings.append(
            Finding(
                "BATT_LOW_VOLT",
                low_volt,
                want,
                "no low-voltage failsafe"
                + ("" if cells > 0 else " (set the adapter's `cells` to let it choose)"),
            )
        )
    return findings
