"""ArduCopter's own failsafes through antalate, one scenario table flown against the real firmware
(ArduCopter 4.6.3 SITL) and against the project's emulator: they must agree on what the operator sees.

Each scenario starts landed in STANDBY, takes off by the operator's TAKEOFF, breaks something with
ArduPilot's own failure injection (``SIM_BATT_VOLTAGE``, ``SIM_GPS_DISABLE``, ``SIM_RC_FAIL``) or a
geofence, and records what the operator sees -- the HLC's states with the failsafe each one names, the
MC's states, the failsafes named in ``hlc_error_t`` -- and what the vehicle did by its own telemetry (the
second ground station, `gcs`). `SCENARIOS` is the expectation for both backends: when the emulator stops
doing what the firmware does, one of the two runs fails on that row.

One vehicle per backend for the whole module (ArduCopter needs ~40 s to be ready), so the order
matters and is part of the test: the battery failsafe comes first and is reset (MAV_CMD_BATTERY_RESET)
-- every later take-off shows that nothing the adapter derived from it stayed latched; the GPS comes
back after its scenario, and the next take-off shows the EKF failsafe did not stay either.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from antalate_lcm.vehicles.mavlink import failsafe as fs
from tests.conftest import Probe, _netns_reason
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.sitl_arducopter.flight import AGENT, command, direction, wait_state
from tests.sitl_arducopter.harness import Copter, sitl_missing

pytestmark = [pytest.mark.netns, pytest.mark.timeout(400)]
HLC_NAMES = {v: k for k, v in vars(H).items() if k.isupper() and isinstance(v, int)}
MC_NAMES = {v: k for k, v in vars(M).items() if k.isupper() and isinstance(v, int)}
#: Where each run's observations go as JSON lines (docs/ardupilot.md's comparison table is made from it).
RESULTS = os.environ.get("ANTALATE_FAILSAFE_RESULTS", "")


@dataclass(frozen=True)
class Scenario:
    """What the operator and the vehicle show after `trigger`, the same for firmware and emulator."""

    name: str
    params: tuple[tuple[str, float], ...]  # set before the take-off
    modes: tuple[str, ...]  # the vehicle's modes after the trigger, in order
    hlc: tuple[tuple[str, str], ...]  # (HLC state, the failsafe its reason names) after AIRBORNE
    mc: tuple[str, ...]  # the MC's states after MISSION
    restore: tuple[tuple[str, float], ...]  # set once landed


BATTERY = Scenario(
    "battery failsafe by voltage during LAND",
    (
        ("BATT_LOW_VOLT", 11.0),
        ("BATT_CRT_VOLT", 10.0),
        ("BATT_LOW_TIMER", 1),
        ("BATT_FS_LOW_ACT", 2),  # RTL
        ("BATT_FS_CRT_ACT", 1),  # LAND
    ),
    ("LAND", "RTL", "LAND"),
    (
        ("LANDING", ""),
        ("RTL", fs.BATTERY),
        ("LANDING", fs.BATTERY),
        ("READY", ""),
    ),
    ("LAND", "RTL", "LAND", "STANDBY"),
    (("SIM_BATT_VOLTAGE", 12.6),),
)
GPS = Scenario(
    "GPS lost (EKF failsafe)",
    (),
    ("LAND",),
    (("LANDING", fs.EKF), ("READY", "")),
    ("LAND", "STANDBY"),
    (("SIM_GPS_DISABLE", 0),),
)
RC = Scenario(
    "RC failsafe",
    (),
    ("RTL",),
    (("RTL", fs.RC), ("READY", "")),
    ("RTL", "STANDBY"),
    (("SIM_RC_FAIL", 0),),
)
FENCE = Scenario(
    "fence breach (circle)",
    (("FENCE_RADIUS", 5), ("RTL_ALT", 1000)),
    ("RTL",),
    (("RTL", fs.FENCE), ("READY", "")),
    ("RTL", "STANDBY"),
    (("FENCE_ENABLE", 0),),
)
SCENARIOS = (BATTERY, GPS, RC, FENCE)


# ---------------------------------------------------------------------------------- operator's side


def named(reason: str) -> str:
    """The failsafe a state's reason or an error's text names ("" for none)."""
    return next((f for f in fs.PRIORITY if f in reason), "")


def changes(probe: Probe, channel: str, kind: str, since: int, before: int) -> list[dict[str, Any]]:
    """The states published since `since`, each change once, without the `before` state still repeated."""
    seen: list[dict[str, Any]] = []
    for m in probe.history(f"{AGENT}/{channel}", kind, since=since):
        if (not seen and m["state"] == before) or (seen and seen[-1]["state"] == m["state"]):
            continue
        seen.append(m)
    return seen


def vehicle_mode(copter: Copter, mode: str, timeout: float) -> None:
    assert wait_for(lambda: copter.gcs.state()["mode"] == mode, timeout=timeout, interval=0.2), (
        mode,
        copter.gcs.state(),
    )


# ---------------------------------------------------------------------------------- the triggers


def battery(copter: Copter, probe: Probe) -> None:
    """The operator lands; the pack sags below BATT_LOW_VOLT, then below BATT_CRT_VOLT."""
    command(probe, O.LAND)
    vehicle_mode(copter, "LAND", 10)
    copter.gcs.set_param("SIM_BATT_VOLTAGE", 10.8)
    vehicle_mode(copter, "RTL", 15)
    time.sleep(1.0)
    copter.gcs.set_param("SIM_BATT_VOLTAGE", 9.8)


def gps(copter: Copter, probe: Probe) -> None:
    copter.gcs.set_param("SIM_GPS_DISABLE", 1)


def rc(copter: Copter, probe: Probe) -> None:
    copter.gcs.set_param("SIM_RC_FAIL", 1)


def fence(copter: Copter, probe: Probe) -> None:
    """East ~10 m, then the 5 m circle is enabled with the copter outside it: a breach.

    The operator alone cannot breach an enabled circle on ArduCopter 4.6.3: in GUIDED its avoidance
    (AC_Avoid, AVOID_ENABLE) stops the velocity FENCE_MARGIN inside the circle -- measured: pushed east
    at the operator's speed into a 30 m circle, the SITL copter stopped at 28.0 m and hovered, GUIDED,
    no breach, no failsafe (the emulator does not model AC_Avoid)."""
    end = time.monotonic() + 4.0
    while time.monotonic() < end:
        direction(probe, 90.0, 3.0)
        time.sleep(0.5)
    assert copter.gcs.state()["east"] > 6.0, copter.gcs.state()
    copter.gcs.set_param("FENCE_ENABLE", 1)


def reset_battery(copter: Copter) -> None:
    """A fresh pack: AP_BattMonitor's failsafe is latched until MAV_CMD_BATTERY_RESET, and a reset while
    the monitor still reads the low voltage fails again within BATT_LOW_TIMER (measured: the reset sent
    right after SIM_BATT_VOLTAGE 12.6 left "PreArm: Battery failsafe"). So: the voltage back first, then
    the reset, until the vehicle reports its battery healthy on its own telemetry -- which the adapter
    hears at the same rate, so the next scenario's TAKEOFF flies (a TAKEOFF a moment earlier is refused,
    "battery low: critical", the transient reason said as it is)."""
    assert wait_for(lambda: copter.gcs.state().get("voltage", 0.0) > 12.0, timeout=10, interval=0.2)
    for _ in range(3):
        time.sleep(2.0)
        copter.gcs.command(mav.MAV_CMD_BATTERY_RESET, 0xFFFF, 100)
        if wait_for(lambda: copter.gcs.state().get("battery_healthy"), timeout=5, interval=0.2):
            time.sleep(1.0)
            return
    raise AssertionError(f"battery still failsafed after 3 resets: {copter.gcs.state()}")


TRIGGERS: dict[str, Callable[[Copter, Probe], None]] = {
    BATTERY.name: battery,
    GPS.name: gps,
    RC.name: rc,
    FENCE.name: fence,
}


# ---------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module", params=["arducopter", "emulator"])
def backend(request: pytest.FixtureRequest) -> str:
    reason = (sitl_missing() if request.param == "arducopter" else None) or _netns_reason()
    if reason:
        pytest.skip(reason)
    return str(request.param)


@pytest.fixture(scope="module")
def fs_netns(backend: str) -> Iterator[NetNamespace]:
    with NetNamespace() as ns:
        yield ns


@pytest.fixture(scope="module")
def fs_probe(fs_netns: NetNamespace) -> Iterator[Probe]:
    yield Probe.start(fs_netns)


@pytest.fixture(scope="module")
def copter(
    backend: str, fs_netns: NetNamespace, fs_probe: Probe, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Copter]:
    c = Copter(
        fs_netns, tmp_path_factory.mktemp(f"fs-{backend}"), nodes=("hlc", "mc", "bma"), backend=backend
    )
    c.gcs.set_param("LAND_SPEED", 150)  # cm/s below LAND_ALT_LOW: shorter landings
    yield c
    c.stop()


# ---------------------------------------------------------------------------------- the scenarios


@pytest.mark.parametrize(
    "scenario", SCENARIOS, ids=[s.name.split(" (")[0].replace(" ", "_") for s in SCENARIOS]
)
def test_failsafe_scenario(copter: Copter, fs_probe: Probe, backend: str, scenario: Scenario) -> None:
    probe = fs_probe
    for name, value in scenario.params:
        copter.gcs.set_param(name, value)
    wait_state(probe, "mc", M.STANDBY, timeout=60, since=probe.mark())
    start = probe.mark()
    sent = time.monotonic()
    command(probe, O.TAKEOFF)
    wait_state(probe, "mc", M.MISSION, timeout=150, since=start)
    wait_state(probe, "hlc", H.AIRBORNE, timeout=60, since=start)
    took_off = time.monotonic() - sent
    # the adapter sets GUIDED once the vehicle is ready to arm: boot -> ready (first scenario only)
    guided = [t for t, m in copter.gcs.ok(op="record")["modes"] if m == "GUIDED"]
    ready = round(guided[0] - copter.booted_at, 1) if guided and scenario is SCENARIOS[0] else None
    mark = probe.mark()
    copter.gcs.ok(op="mark")
    TRIGGERS[scenario.name](copter, probe)
    wait_state(probe, "mc", M.STANDBY, timeout=150, since=mark)
    wait_state(probe, "hlc", H.READY, timeout=15, since=mark)
    assert wait_for(lambda: not copter.gcs.state()["armed"], timeout=20, interval=0.2), copter.gcs.state()
    for name, value in scenario.restore:
        copter.gcs.set_param(name, value)
    if scenario is BATTERY:
        reset_battery(copter)
    record = copter.gcs.ok(op="record")
    down = copter.gcs.state()
    seen = {
        "backend": backend,
        "scenario": scenario.name,
        "modes": [m for _, m in record["modes"]],
        "hlc": [
            (HLC_NAMES[m["state"]], named(m["reason"]))
            for m in changes(probe, "HLC_STATE", "hlc_state_t", mark, H.AIRBORNE)
        ],
        "mc": [MC_NAMES[m["state"]] for m in changes(probe, "MC_STATE", "mc_state_t", mark, M.MISSION)],
        "errors": sorted(
            {named(e["text"]) for e in probe.history(f"{AGENT}/HLC_ERROR", "hlc_error_t", since=mark)} - {""}
        ),
        "texts": [t for _, _, t in record["texts"] if fs.text_failsafe(t) or "ailsafe" in t],
        "max_alt": round(record["max_alt"], 1),
        "takeoff_s": round(took_off, 1),
        "boot_to_ready_s": ready,
        "home_m": round(max(abs(down["north"]), abs(down["east"])), 1),
    }
    print(f"\nFAILSAFE {json.dumps(seen)}")
    if RESULTS:
        with Path(RESULTS).open("a") as out:
            out.write(json.dumps(seen) + "\n")
    # what the operator sees and what the vehicle did: the table's row, for both backends
    assert (seen["modes"], seen["hlc"], seen["mc"]) == (
        list(scenario.modes),
        [tuple(h) for h in scenario.hlc],
        list(scenario.mc),
    ), seen
    failsafe = next(f for _, f in scenario.hlc if f)
    assert seen["errors"] == [failsafe], seen  # the hlc_error_t the console shows names it too
    assert seen["home_m"] < 3.0, seen  # it came down at home (every scenario starts there or returns)
    if scenario is FENCE:
        assert seen["max_alt"] >= 9.5, seen  # mode_rtl.cpp: up to RTL_ALT (10 m) before the return
