"""A whole mission through `TelloAdapter` over a `MemoryLink`: no socket, no network namespace (issue #14).

The adapter's link is the Tello emulator's `MemoryLink` (``TelloEmulator(memory=True)``): SDK commands
go to the emulator's model as the datagrams they would be, its answers come back when its manoeuvres
end, and its state lines are the Tello's text, parsed as djitellopy parses them. MC + HLC + an
``auto_operator`` BMA on ``memq://`` fly it: TAKEOFF, airborne, the operator's RTL, landed at the
take-off point. Also the scripted form a user's own test takes: a few lines of Tello as the handler.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import pytest

from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.tello import MemoryLink, Params, TelloAdapter
from antalate_lcm.vehicles.tello.link import parse_state
from tests.emulators.tello_emulator import TelloEmulator
from tests.harness.memory_agent import MemoryAgent
from tests.vehicles.test_tello_e2e import config

EMU: dict[str, Any] = {"takeoff_time": 0.5, "land_speed": 2.0, "max_vertical_speed": 1.5}
AP: dict[str, Any] = config()["hlc"]["autopilot_params"]  # test_tello_e2e's brisk Tello


@pytest.fixture
def emulator() -> Iterator[TelloEmulator]:
    emu = TelloEmulator(memory=True, **EMU).start()
    yield emu
    emu.stop()


def test_mission_over_a_memory_link(emulator: TelloEmulator) -> None:
    """Operator TAKEOFF -> AIRBORNE/MISSION -> RTL -> LANDING -> landed, READY/STANDBY again."""
    link = emulator.link
    assert link is not None
    opened: list[Params] = []

    def open_link(params: Params) -> MemoryLink:
        opened.append(params)
        return link

    agent = MemoryAgent(
        "tello",
        AP,
        hlc={"default_takeoff_altitude": 1.2, "gain_altitude_timeout": 6.0, "link_timeout": 1.5},
        operator={"altitude": 1.2, "rtl_after": 1.0},
        adapter=TelloAdapter(AP, link=open_link),
    ).start()
    try:
        agent.wait("mc", M.STANDBY)
        takeoff = agent.wait("mc", M.TAKEOFF)
        airborne = agent.wait("hlc", H.AIRBORNE, since=takeoff.t)
        assert emulator.snapshot().z == pytest.approx(1.2, abs=0.15)
        rtl = agent.wait("mc", M.RTL, since=airborne.t)
        agent.wait("hlc", H.LANDING, since=rtl.t)
        agent.wait("hlc", H.READY, timeout=15, since=rtl.t)
        agent.wait("mc", M.STANDBY, timeout=5, since=rtl.t)
    finally:
        agent.stop()
    snap = emulator.snapshot()
    assert not snap.flying and math.hypot(snap.x, snap.y) < 0.5
    assert len(opened) == 1 and link.closed  # one link, closed with the agent
    texts = emulator.command_texts()
    assert texts[0] == "command" and "takeoff" in texts and "land" in texts
    assert not agent.errors


def test_scripted_tello_answers_and_state_lines() -> None:
    """What a user's own test does without the emulator: a handler answering the SDK, state pushed by hand."""
    line = "pitch:0;roll:0;yaw:90;vgx:0;vgy:0;vgz:0;templ:60;temph:62;tof:10;h:0;bat:87;baro:100.25;time:0;agx:0.00;agy:0.00;agz:-1000.00;\r\n"

    def tello(command: str) -> str | None:
        link.push_state(line)  # a real Tello streams state once in SDK mode
        return None if command.startswith("rc ") else "87" if command == "battery?" else "ok"

    link = MemoryLink(tello)
    ap = TelloAdapter({**AP, "min_battery": 20.0}, link=lambda _params: link)
    ap.connect()
    try:
        assert ap.arm()  # battery? -> 87 > min_battery
        state = ap.state()
        assert state.battery == 87.0 and not state.in_air and state.heading == pytest.approx(135.0)
        with pytest.raises(AutopilotError, match="altitude"):
            ap.takeoff(-1.0)  # refused before anything is sent
    finally:
        ap.close()
    assert link.closed and link.sent[:2] == ["command", "battery?"]
    assert parse_state(line)["baro"] == 100.25 and parse_state(line)["h"] == 0
    assert parse_state("mpry:1,2,3;h:x;") == {"mpry": "1,2,3"}  # a field that does not parse is left out
