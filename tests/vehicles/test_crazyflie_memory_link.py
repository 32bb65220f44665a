"""A whole mission through `CrazyflieAdapter` over ``memory://``: the real cflib stack, no radio, no socket.

The adapter is configured exactly as for a Crazyflie (``uri`` in ``[hlc.autopilot_params]``); cflib
picks the in-memory driver by the URI's scheme (`crazyflie.memory.install` put it in cflib's driver
list) and the driver hands every CRTP packet to the emulator's model, which answers with the same
bytes it would send over UDP. MC + HLC + an ``auto_operator`` BMA on ``memq://`` fly it: TAKEOFF,
airborne, the operator's RTL, landed at the take-off point.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from tests.harness.memory_agent import MemoryAgent

pytest.importorskip("cflib")

from antalate_lcm.vehicles.crazyflie.memory import MemoryDriver, MemoryLink  # noqa: E402
from tests.emulators.crazyflie_emulator import CrazyflieEmulator  # noqa: E402

FAST_AP = {"climb_speed": 2.0, "land_speed": 1.0, "rtl_speed": 2.0, "connect_timeout": 8.0}


@pytest.fixture
def emulator() -> Iterator[CrazyflieEmulator]:
    emu = CrazyflieEmulator(memory="cf-mission").start()
    yield emu
    emu.stop()


def test_mission_over_memory_uri(emulator: CrazyflieEmulator) -> None:
    """Operator TAKEOFF -> AIRBORNE/MISSION -> RTL -> landed at the take-off point, READY/STANDBY again."""
    assert emulator.uri == "memory://cf-mission"
    agent = MemoryAgent(
        "crazyflie",
        {**FAST_AP, "uri": emulator.uri},
        hlc={"default_takeoff_altitude": 1.0, "gain_altitude_timeout": 8.0, "link_timeout": 1.0},
        operator={"altitude": 1.0, "rtl_after": 1.0},
    ).start()
    try:
        agent.wait("mc", M.STANDBY)
        takeoff = agent.wait("mc", M.TAKEOFF)
        airborne = agent.wait("hlc", H.AIRBORNE, since=takeoff.t)
        assert emulator.snapshot().z > 0.8
        rtl = agent.wait("mc", M.RTL, since=airborne.t)
        agent.wait("hlc", H.RTL, timeout=4, since=rtl.t)
        agent.wait("hlc", H.READY, timeout=15, since=rtl.t)
        agent.wait("mc", M.STANDBY, timeout=5, since=rtl.t)
    finally:
        agent.stop()
    after = emulator.snapshot()
    assert not after.flying and after.z < 0.1 and math.hypot(after.x, after.y) < 0.3
    assert emulator.hl_commands and emulator.received  # cflib's packets reached the model
    assert not agent.errors


def test_memory_link_names_are_unique_and_unknown_names_fail() -> None:
    """Two peers cannot share a name; a URI naming no peer is refused at connect, not left hanging."""
    link = MemoryLink("cf-unique", lambda _packet: None)
    try:
        with pytest.raises(ValueError, match="already registered"):
            MemoryLink("cf-unique", lambda _packet: None)
        driver = MemoryDriver()
        with pytest.raises(ConnectionError, match="no memory link named 'cf-missing'"):
            driver.connect("memory://cf-missing", None, None)
    finally:
        link.close()
    MemoryLink("cf-unique", lambda _packet: None).close()  # the name is free again once closed
