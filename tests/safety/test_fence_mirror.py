"""The swarm fence mirrored into ArduCopter's FENCE_* parameters: the values (pure), then written to and
read back from the MAVLink vehicle emulator through the adapter's PARAM_SET / PARAM_REQUEST_READ."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.vehicles.mavlink import MavlinkAdapter
from antalate_lcm.vehicles.mavlink.fence_mirror import ORDER, fence_parameters, mirror, mismatches
from tests.emulators.mavlink_vehicle import MavlinkVehicle
from tests.vehicles.test_mavlink_adapter import FAST, make_ap

FENCE = Geofence(((-30.0, -40.0), (-30.0, 40.0), (50.0, 40.0), (50.0, -40.0)), 3.0, 60.0, 2.0)


def test_the_circumscribed_cylinder_around_home() -> None:
    p = fence_parameters(FENCE, (0.0, 0.0))
    # the farthest vertex from home is (50, +-40): 64.03 m, plus the 2 m margin
    assert p["FENCE_RADIUS"] == pytest.approx(66.0, abs=0.05)
    assert p["FENCE_TYPE"] == 1 | 2 | 8 and p["FENCE_ALT_MAX"] == 60.0 and p["FENCE_ALT_MIN"] == 3.0
    assert p["FENCE_MARGIN"] == 2.0 and p["FENCE_ACTION"] == 1 and p["FENCE_ENABLE"] == 1
    no_floor = Geofence(FENCE.polygon, 0.0, 60.0, 2.0)
    q = fence_parameters(no_floor, (10.0, 0.0), "land")
    assert q["FENCE_TYPE"] == 1 | 2 and q["FENCE_ACTION"] == 2
    assert fence_parameters(FENCE, (0.0, 0.0), "hover")["FENCE_ACTION"] == 4
    assert list(p) == list(ORDER)  # FENCE_ENABLE last: never a fence enabled half-set


def test_mismatches_name_the_parameter() -> None:
    wanted = {"FENCE_RADIUS": 66.0, "FENCE_ALT_MIN": 3.0, "FENCE_ENABLE": 1.0}
    read = {"FENCE_RADIUS": 66.00001, "FENCE_ENABLE": 0.0}
    assert mismatches(wanted, read) == ["FENCE_ALT_MIN not reported", "FENCE_ENABLE = 0, wanted 1"]


@pytest.fixture
def vehicle() -> Iterator[MavlinkVehicle]:
    with MavlinkVehicle("127.0.0.1", 0, 0, **FAST) as v:
        yield v


def test_written_to_the_vehicle_and_read_back(vehicle: MavlinkVehicle) -> None:
    ap: MavlinkAdapter = make_ap(vehicle.udp_url)
    try:
        ap.connect()
        wanted = fence_parameters(FENCE, (0.0, 0.0))
        assert vehicle.param("FENCE_ENABLE") == 0 and vehicle.param("FENCE_RADIUS") == 300.0
        assert mirror(ap, wanted) == []
        for name, value in wanted.items():
            assert vehicle.param(name) == pytest.approx(value, rel=1e-6), name
    finally:
        ap.close()


def test_the_hlc_mirrors_its_fence_before_flying_and_says_so() -> None:
    """MC + HLC(mavlink) + the auto-operator on memq://, [safety] with a fence: the HLC writes the fence
    on the ground, reads it back, reports it (SAFETY, INFO), and the sortie still flies and lands."""
    from antalate_lcm.agent.hlc.machine import ErrorCode
    from antalate_lcm.msgs import hlc_error_t
    from antalate_lcm.msgs import mc_state_t as M
    from tests.emulators.mavlink_vehicle import BRISK
    from tests.harness.memory_agent import MemoryAgent
    from tests.vehicles.test_mavlink_e2e import AP, AUTO_OPERATOR

    vehicle = MavlinkVehicle("127.0.0.1", 0, **BRISK).start()
    home = vehicle.snapshot()
    polygon = [[-30.0, -40.0], [-30.0, 40.0], [50.0, 40.0], [50.0, -40.0]]
    safety = {
        "enabled": True,
        "origin": [home.lat, home.lon],
        "fence": {"polygon": polygon, "floor": 0.0, "ceiling": 60.0, "margin": 2.0, "outside": "land"},
    }
    agent = MemoryAgent(
        "mavlink",
        {"connection": vehicle.udp_url, **AP},
        name="copter",
        hlc={"default_takeoff_altitude": 3.0},
        operator={**AUTO_OPERATOR, "rtl_after": 1.0},
        safety=safety,
    )
    try:
        agent.start()
        err = agent.error(ErrorCode.SAFETY, timeout=15)
        assert (
            err.severity == hlc_error_t.INFO and "fence mirrored into the autopilot and read back" in err.text
        )
        assert vehicle.param("FENCE_ENABLE") == 1 and vehicle.param("FENCE_ACTION") == 2
        assert vehicle.param("FENCE_ALT_MAX") == 60.0 and vehicle.param("FENCE_TYPE") == 1 | 2
        assert vehicle.param("FENCE_RADIUS") == pytest.approx(66.0, abs=0.1)
        mission = agent.wait("mc", M.MISSION, timeout=20)
        agent.wait("mc", M.STANDBY, timeout=30, since=mission.t)
    finally:
        agent.stop()
        vehicle.stop()


def test_px4_gets_the_same_cylinder_in_its_gf_parameters_without_a_floor() -> None:
    """PX4 v1.15.4 (geofence_params.c): GF_MAX_HOR_DIST around home, GF_MAX_VER_DIST above it, GF_ACTION
    (2 Hold, 3 Return, 5 Land); no floor parameter, the action written last."""
    from antalate_lcm.vehicles.px4.fence_mirror import ORDER as PX4_ORDER
    from antalate_lcm.vehicles.px4.fence_mirror import fence_parameters as px4_parameters

    p = px4_parameters(FENCE, (0.0, 0.0))
    assert p == {"GF_MAX_HOR_DIST": pytest.approx(66.0, abs=0.05), "GF_MAX_VER_DIST": 60.0, "GF_ACTION": 3.0}
    assert list(p) == list(PX4_ORDER) and PX4_ORDER[-1] == "GF_ACTION"
    assert px4_parameters(FENCE, (10.0, 0.0), "land")["GF_ACTION"] == 5.0
    assert px4_parameters(FENCE, (0.0, 0.0), "hover")["GF_ACTION"] == 2.0
    # from a home 10 m north the farthest vertex is (-30, +-40): 56.57 m + 2 m margin
    assert px4_parameters(FENCE, (10.0, 0.0))["GF_MAX_HOR_DIST"] == pytest.approx(58.6, abs=0.05)
