"""The vehicle pre-flight checks: ArduCopter's own failsafe parameters read, reported, configured, or arming refused.

Pure checks first (`vehicle_checks.check`), then the adapter against the emulator's parameters through
PARAM_REQUEST_READ / PARAM_SET / PARAM_VALUE.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from antalate_lcm.vehicles.mavlink import MavlinkAdapter
from antalate_lcm.vehicles.mavlink.vehicle_checks import READ, Finding, check
from tests.emulators.mavlink_vehicle import MavlinkVehicle
from tests.vehicles.test_mavlink_adapter import FAST, make_ap

# What docs/ardupilot.md asks for, with antalate as system 245.
GOOD: dict[str, float] = {
    "FS_GCS_ENABLE": 1,
    "FS_GCS_TIMEOUT": 5,
    "SYSID_MYGCS": 245,
    "GUID_TIMEOUT": 3,
    "FENCE_ENABLE": 1,
    "FENCE_ACTION": 1,
    "BATT_MONITOR": 4,
    "BATT_FS_LOW_ACT": 2,
    "BATT_LOW_VOLT": 10.5,
}


def findings(values: dict[str, float], cells: int = 0) -> dict[str, Finding]:
    return {f.param: f for f in check(values, source_system=245, max_guid_timeout=3.0, cells=cells)}


def test_a_vehicle_set_up_as_documented_passes() -> None:
    assert findings(GOOD) == {}
    # Copter 4.7 calls SYSID_MYGCS MAV_GCS_SYSID; older firmware has no GUID_TIMEOUT/FS_GCS_TIMEOUT (3 s, 5 s fixed)
    renamed = {k: v for k, v in GOOD.items() if k not in ("SYSID_MYGCS", "GUID_TIMEOUT", "FS_GCS_TIMEOUT")}
    assert findings({**renamed, "MAV_GCS_SYSID": 245}) == {}


def test_each_unprotected_parameter_is_named_with_the_value_to_set() -> None:
    defaults = {
        **GOOD,
        "FS_GCS_ENABLE": 0,
        "SYSID_MYGCS": 255,
        "GUID_TIMEOUT": 5,
        "FENCE_ENABLE": 0,
        "FENCE_ACTION": 0,
        "BATT_FS_LOW_ACT": 0,
        "BATT_LOW_VOLT": 0,
    }
    got = findings(defaults)
    assert set(got) == {
        "FS_GCS_ENABLE",
        "SYSID_MYGCS",
        "GUID_TIMEOUT",
        "FENCE_ENABLE",
        "FENCE_ACTION",
        "BATT_FS_LOW_ACT",
        "BATT_LOW_VOLT",
    }
    assert got["SYSID_MYGCS"].text() == (
        "SYSID_MYGCS = 255 (the GCS failsafe watches system 255, antalate sends as 245): set SYSID_MYGCS = 245"
    )
    assert (
        got["FS_GCS_ENABLE"].want == 1
        and got["GUID_TIMEOUT"].want == 3.0
        and got["BATT_FS_LOW_ACT"].want == 2
    )
    # a low-voltage threshold is only chosen knowing the cells (3.4 V each: below the HLC's 3.5 V)
    assert got["BATT_LOW_VOLT"].want is None and "cells" in got["BATT_LOW_VOLT"].text()
    assert findings(defaults, cells=4)["BATT_LOW_VOLT"].want == pytest.approx(13.6)
    # what only a person can fix, and what the vehicle did not report
    no_monitor = findings({**GOOD, "BATT_MONITOR": 0})["BATT_MONITOR"]
    assert not no_monitor.settable and "configure it on the vehicle" in no_monitor.text()
    missing = findings({k: v for k, v in GOOD.items() if k not in ("FENCE_ENABLE", "SYSID_MYGCS")})
    assert missing["FENCE_ENABLE"].text().startswith("FENCE_ENABLE not reported")
    assert missing["SYSID_MYGCS"].value is None and set(READ) >= set(GOOD)


@pytest.fixture
def vehicle(request: pytest.FixtureRequest) -> Iterator[MavlinkVehicle]:
    with MavlinkVehicle("127.0.0.1", 0, **{**FAST, **getattr(request, "param", {})}) as v:
        yield v


def adapter(vehicle: MavlinkVehicle, made: list[MavlinkAdapter], **params: Any) -> MavlinkAdapter:
    ap = make_ap(vehicle.udp_url, **params)
    made.append(ap)
    ap.connect()
    return ap


def test_defaults_are_reported_and_arming_still_allowed(
    vehicle: MavlinkVehicle, made: list[MavlinkAdapter], caplog: pytest.LogCaptureFixture
) -> None:
    ap = adapter(
        vehicle, made
    )  # ArduCopter's defaults: no GCS failsafe, GCS 255, no fence, no battery action
    assert {f.param for f in ap.vehicle_findings} == {
        "FS_GCS_ENABLE",
        "SYSID_MYGCS",
        "FENCE_ENABLE",
        "BATT_FS_LOW_ACT",
    }
    assert (
        "vehicle pre-flight check: SYSID_MYGCS = 255" in caplog.text
        and "set SYSID_MYGCS = 245" in caplog.text
    )
    assert vehicle.param("SYSID_MYGCS") == 255  # reported, not touched
    assert ap.arm() is True


def test_required_failsafes_refuse_arming_naming_the_parameter(
    vehicle: MavlinkVehicle, made: list[MavlinkAdapter]
) -> None:
    ap = adapter(vehicle, made, require_vehicle_failsafes=True)
    assert ap.arm() is False
    assert ap.last_refusal.startswith("vehicle pre-flight check: FS_GCS_ENABLE = 0")
    assert "set SYSID_MYGCS = 245" in ap.last_refusal and "set FENCE_ENABLE = 1" in ap.last_refusal
    assert not vehicle.snapshot().armed and vehicle.snapshot().mode == "STABILIZE"  # nothing was touched
    # someone fixes the vehicle (a ground station's PARAM_SET): the next arm reads again and flies
    for name, value in (
        ("FS_GCS_ENABLE", 1),
        ("SYSID_MYGCS", 245),
        ("FENCE_ENABLE", 1),
        ("BATT_FS_LOW_ACT", 2),
    ):
        ap.set_param(name, value)
    assert ap.arm() is True and ap.vehicle_findings == []


@pytest.mark.parametrize(
    "vehicle",
    [{"gcs_sysid_param": "MAV_GCS_SYSID", "params": {"GUID_TIMEOUT": 5.0, "BATT_LOW_VOLT": 0.0}}],
    indirect=True,
)
def test_configure_vehicle_writes_what_is_wrong(vehicle: MavlinkVehicle, made: list[MavlinkAdapter]) -> None:
    ap = adapter(vehicle, made, configure_vehicle=True, require_vehicle_failsafes=True, cells=4)
    assert ap.vehicle_findings == []
    assert vehicle.param("FS_GCS_ENABLE") == 1 and vehicle.param("MAV_GCS_SYSID") == 245  # Copter 4.7's name
    assert vehicle.param("GUID_TIMEOUT") == 3.0 and vehicle.param("FENCE_ENABLE") == 1
    assert vehicle.param("BATT_FS_LOW_ACT") == 2 and vehicle.param("BATT_LOW_VOLT") == pytest.approx(13.6)
    sets = {r.fields["param_id"] for r in vehicle.received_of("PARAM_SET")}
    assert sets == {
        "FS_GCS_ENABLE",
        "MAV_GCS_SYSID",
        "GUID_TIMEOUT",
        "FENCE_ENABLE",
        "BATT_FS_LOW_ACT",
        "BATT_LOW_VOLT",
    }
    assert ap.arm() is True


@pytest.mark.parametrize("vehicle", [{"params": {"BATT_MONITOR": 0}}], indirect=True)
def test_what_the_adapter_cannot_set_still_refuses(
    vehicle: MavlinkVehicle, made: list[MavlinkAdapter]
) -> None:
    ap = adapter(vehicle, made, configure_vehicle=True, require_vehicle_failsafes=True)
    assert [f.param for f in ap.vehicle_findings] == ["BATT_MONITOR"]
    assert ap.arm() is False and "BATT_MONITOR = 0" in ap.last_refusal
    assert ap.read_params(["NO_SUCH_PARAM"]) == {}  # ArduPilot does not answer: left out, not invented


def test_without_the_connect_check_arming_still_checks_when_required(
    vehicle: MavlinkVehicle, made: list[MavlinkAdapter]
) -> None:
    ap = adapter(vehicle, made, check_vehicle=False, require_vehicle_failsafes=True)
    assert ap.vehicle_findings == [] and not vehicle.received_of("PARAM_REQUEST_READ")
    assert ap.arm() is False  # required: checked at arm time
    assert "FS_GCS_ENABLE" in ap.last_refusal
    assert ap.state().connected
