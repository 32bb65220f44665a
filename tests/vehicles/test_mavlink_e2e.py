"""Whole agents flying the ArduCopter-like emulator through `MavlinkAdapter` (docs/design.md §5, §6, §7).

Two set-ups:

* **In process** (the failsafes): MC + HLC(``mavlink``) + a BMA running ``auto_operator`` on one
  ``memq://`` bus in the test process, the emulator on 127.0.0.1 -- so the test can inject faults
  straight into the vehicle (``refuse_arm``, ``set_battery``, ``stop_heartbeats``,
  ``pilot_switch_mode``) and watch the MC and HLC states.
* **Separate processes in a private network namespace**: ``antalate agent`` / ``antalate hlc`` +
  ``antalate mc`` over real multicast, the emulator as its own process (``python -m
  tests.emulators.mavlink_vehicle``) in the same namespace -- a whole mission, an HLC killed and
  restarted mid-flight that resynchronises to AIRBORNE without arming or taking off again, and an HLC
  killed for good: the vehicle's own GCS failsafe (set up as docs/ardupilot.md says) brings it home.

In process too: a link cut for 5 s that buffers and flushes (RTL home with no operator action), and a
fence breach that ArduCopter answers with BRAKE (the HLC holds, the operator's LAND is accepted).
"""

from __future__ import annotations

import json
import math
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.agent.hlc.machine import ErrorCode
from antalate_lcm.msgs import hlc_error_t, operator_cmd_t
from antalate_lcm.msgs import hlc_state_t as H
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from antalate_lcm.vehicles.mavlink import LinkOpener, MavlinkAdapter
from tests.conftest import MCAST_URL, Probe
from tests.emulators.mavlink_vehicle import BRISK, MavlinkVehicle
from tests.harness.agents import AgentProcesses
from tests.harness.memory_agent import MemoryAgent
from tests.harness.netns import NetNamespace
from tests.harness.process import stop_process

AP: dict[str, Any] = {
    "stream_rate_hz": 20.0,
    "connect_timeout": 5.0,
    "ready_timeout": 5.0,
    "ack_timeout": 0.5,
}
AUTO_OPERATOR: dict[str, Any] = {"altitude": 3.0, "max_flights": 1, "retry": 0.5}


def _bma(**operator: Any) -> list[dict[str, Any]]:
    return [
        {
            "name": "operator",
            "behaviors": [
                {
                    "plugin": "auto_operator",
                    "activate_on": ["STANDBY", "MISSION"],
                    "params": {**AUTO_OPERATOR, **operator},
                }
            ],
        }
    ]


class InProcessAgent(MemoryAgent):
    """MC + HLC + auto_operator BMA on memq://, flying `vehicle` (over UDP, or the test's own `link`)."""

    def __init__(
        self,
        vehicle: MavlinkVehicle,
        *,
        hlc: dict[str, Any] | None = None,
        operator: dict[str, Any] | None = None,
        link: LinkOpener | None = None,
    ) -> None:
        connection = vehicle.udp_url if link is None else "memory:emulator"
        params = {"connection": connection, **AP}
        super().__init__(
            "mavlink",
            params,
            name="copter",
            hlc={"default_takeoff_altitude": 3.0, "link_timeout": 1.5, **(hlc or {})},
            operator={**AUTO_OPERATOR, **(operator or {})},
            adapter=None if link is None else MavlinkAdapter(params, link=link),
        )
        self.vehicle = vehicle


@pytest.fixture
def copter() -> Iterator[Callable[..., InProcessAgent]]:
    made: list[tuple[MavlinkVehicle, InProcessAgent]] = []

    def make(vehicle: dict[str, Any] | None = None, **kw: Any) -> InProcessAgent:
        v = MavlinkVehicle("127.0.0.1", 0, **{**BRISK, **(vehicle or {})}).start()
        agent = InProcessAgent(v, **kw)
        made.append((v, agent))
        return agent.start()

    yield make
    for v, agent in made:
        agent.stop()
        v.stop()


def flying(agent: InProcessAgent) -> float:
    """Wait for the auto-operator's sortie to reach MISSION; the time it did."""
    agent.wait("mc", M.STANDBY)
    agent.wait("hlc", H.AIRBORNE, timeout=10)
    return agent.wait("mc", M.MISSION).t


# -- the failsafes of docs/design.md §6, in process ----------------------------------------------------------


def test_arming_refused_back_to_ready_with_an_error_then_flies(copter: Callable[..., InProcessAgent]) -> None:
    agent = copter()
    agent.vehicle.refuse_arm = True
    agent.wait("mc", M.STANDBY)
    agent.wait("mc", M.TAKEOFF)
    err = agent.error(ErrorCode.ARM_FAILED)
    assert err.severity == hlc_error_t.ERROR and "arm" in err.text
    back = agent.wait("mc", M.STANDBY, since=agent.wait("mc", M.TAKEOFF).t)
    assert H.READY in agent.states("hlc")[agent.states("hlc").index(H.TAKEOFF) :]
    assert not agent.vehicle.snapshot().armed
    # the pre-arm problem cleared: the auto-operator's retry flies
    agent.vehicle.refuse_arm = False
    agent.wait("mc", M.MISSION, timeout=10, since=back.t)
    assert agent.vehicle.snapshot().armed and agent.vehicle.snapshot().mode == "GUIDED"


def test_low_battery_returns_home(copter: Callable[..., InProcessAgent]) -> None:
    agent = copter(hlc={"low_battery": 20.0})
    flying(agent)
    agent.vehicle.set_battery(18)
    agent.wait("hlc", H.LOW_BATTERY, timeout=3)
    agent.error(ErrorCode.LOW_BATTERY)
    agent.wait("mc", M.RTL)
    # the MC's RTL and the HLC's mode command to the vehicle go out together: wait for the vehicle
    assert agent.vehicle.wait_until(lambda s: s.mode == "RTL", 3)
    agent.wait("mc", M.STANDBY, timeout=10, since=agent.wait("mc", M.RTL).t)
    assert agent.wait("hlc", H.READY, since=agent.wait("hlc", H.LOW_BATTERY).t)
    snap = agent.vehicle.snapshot()
    assert not snap.armed and math.hypot(snap.north, snap.east) < 0.5


def test_link_cut_5_s_then_restored_returns_home_without_the_operator(
    copter: Callable[..., InProcessAgent],
) -> None:
    """A TCP-like cut that keeps everything written to it and flushes it when the link returns."""
    agent = copter(hlc={"link_timeout": 1.5})
    flying(agent)
    cut = time.monotonic()
    agent.vehicle.cut_link()
    down = agent.wait("hlc", H.LLC_DOWN, timeout=4)
    assert 1.4 <= down.t - cut < 3.0
    agent.error(ErrorCode.LINK_LOST)
    time.sleep(max(0.0, cut + 5.0 - time.monotonic()))
    before = agent.vehicle.snapshot()
    agent.vehicle.restore_link()
    back = agent.wait("hlc", H.HOLD, timeout=4, since=down.t)
    assert "regained" in agent.error(ErrorCode.LINK_REGAINED).text
    agent.wait("mc", M.RTL, timeout=4, since=back.t)  # [mc] on_link_regained = "rtl": nobody pressed anything
    agent.wait("hlc", H.RTL, timeout=4, since=back.t)
    assert agent.vehicle.wait_until(lambda s: s.mode == "RTL", 4)
    agent.wait("mc", M.STANDBY, timeout=15, since=back.t)
    agent.wait("hlc", H.READY, timeout=5, since=back.t)
    after = agent.vehicle.snapshot()
    assert not after.armed and math.hypot(after.north, after.east) < 0.5
    assert abs(before.alt - 3.0) < 0.5  # it hovered through the cut (GUIDED holds after GUID_TIMEOUT)
    assert not [e for e in agent.errors if e.code == ErrorCode.PILOT_TAKEOVER]


def test_fence_breach_holds_and_the_operator_lands(copter: Callable[..., InProcessAgent]) -> None:
    """FENCE_ACTION 4: ArduCopter brakes at the fence; the HLC holds with it (not MANUAL); LAND from the operator."""
    agent = copter(vehicle={"params": {"FENCE_ENABLE": 1, "FENCE_ALT_MAX": 2.0, "FENCE_ACTION": 4}})
    agent.wait("mc", M.STANDBY)
    hold = agent.wait("hlc", H.HOLD, timeout=10)  # the takeoff to 3 m breaks the 2 m ceiling
    assert agent.vehicle.snapshot().mode == "BRAKE"
    err = agent.error(ErrorCode.AUTOPILOT_FAILSAFE)
    assert "fence breach" in err.text and err.severity == hlc_error_t.WARNING
    assert H.MANUAL not in agent.states("hlc") and M.MANUAL not in agent.states("mc")
    time.sleep(0.5)
    assert agent.states("hlc")[-1] == H.HOLD and agent.vehicle.snapshot().armed  # it waits for the operator
    land = operator_cmd_t()
    land.command = O.LAND
    agent.probe.publish("OPERATOR_CMD", land)
    agent.wait("hlc", H.LANDING, timeout=4, since=hold.t)
    assert agent.vehicle.wait_until(lambda s: s.mode == "LAND", 3)
    agent.wait("hlc", H.READY, timeout=8, since=hold.t)
    agent.wait("mc", M.STANDBY, timeout=4, since=hold.t)
    assert not agent.vehicle.snapshot().armed


def test_pilot_takeover_is_manual_until_the_pilot_lands(copter: Callable[..., InProcessAgent]) -> None:
    agent = copter()
    flying(agent)
    assert agent.vehicle.pilot_switch_mode("LOITER")
    manual = agent.wait("hlc", H.MANUAL, timeout=3)
    agent.error(ErrorCode.PILOT_TAKEOVER)
    agent.wait("mc", M.MANUAL)
    time.sleep(0.5)  # the HLC leaves the pilot alone: no mode change, no velocity target
    snap = agent.vehicle.snapshot()
    assert snap.mode == "LOITER" and snap.armed
    assert not [r for r in agent.vehicle.received_of("SET_POSITION_TARGET_LOCAL_NED") if r.t > manual.t + 0.3]
    assert agent.vehicle.pilot_switch_mode("LAND")  # the pilot lands
    agent.wait("hlc", H.READY, timeout=8, since=manual.t)
    agent.wait("mc", M.STANDBY, since=manual.t)
    time.sleep(0.5)  # max_flights = 1: it stays down
    assert agent.states("mc")[-1] == M.STANDBY and not agent.vehicle.snapshot().armed


def test_altitude_not_gained_lands(copter: Callable[..., InProcessAgent]) -> None:
    agent = copter(vehicle={"climb_rate": 0.2}, hlc={"gain_altitude_timeout": 1.5})
    agent.wait("mc", M.STANDBY)
    climbing = agent.wait("hlc", H.GAINING_ALTITUDE, timeout=10)
    landing = agent.wait("hlc", H.LANDING, timeout=4)
    assert 1.4 <= landing.t - climbing.t < 2.5
    assert "not gained" in agent.error(ErrorCode.GAIN_ALTITUDE_TIMEOUT).text
    agent.wait("mc", M.LAND)
    assert agent.vehicle.snapshot().mode == "LAND"
    agent.wait("hlc", H.READY, timeout=8, since=landing.t)
    agent.wait("mc", M.STANDBY, since=landing.t)
    assert M.MISSION not in agent.states("mc")


# -- separate processes in a private namespace ---------------------------------------------------------


class EmulatorProcess:
    """``python -m tests.emulators.mavlink_vehicle`` inside the namespace; its final JSON snapshot on stop."""

    def __init__(self, netns: NetNamespace, *args: str) -> None:
        self.proc = netns.python(
            "-m",
            "tests.emulators.mavlink_vehicle",
            "--host",
            "127.0.0.1",
            "--udp-port",
            "0",
            "--tcp-port",
            "0",
            "--boot-delay",
            "0.3",
            "--ekf-delay",
            "0.6",
            "--gps-delay",
            "0.5",
            *args,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        assert self.proc.stdout is not None
        ready = self.proc.stdout.readline().split()
        assert ready and ready[0] == "READY", ready
        self.udp_port = int(ready[1].removeprefix("udp="))
        self.tcp_port = int(ready[2].removeprefix("tcp="))
        self.final: dict[str, Any] | None = None

    def stop(self) -> dict[str, Any]:
        if self.final is None:
            self.proc.send_signal(15)
            out, _err = self.proc.communicate(timeout=5)
            self.final = json.loads(out.strip().splitlines()[-1])
        return self.final


@pytest.fixture
def emulator(netns: NetNamespace) -> Iterator[EmulatorProcess]:
    emu = EmulatorProcess(netns)
    yield emu
    if emu.proc.poll() is None:
        stop_process(emu.proc)


def process_doc(name: str, connection: str, bma: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "agent": {"name": name},
        "buses": {"lan": MCAST_URL},
        "hlc": {
            "autopilot": "mavlink",
            "default_takeoff_altitude": 3.0,
            "autopilot_params": {"connection": connection, "ack_timeout": 1.0, "stream_rate_hz": 10.0},
        },
        # unsigned operator commands from the probe, MC and HLC in separate processes: this file tests the
        # adapter, docs/security.md and its tests the keys
        "security": {"insecure": True},
    }
    if bma:
        doc["bma"] = bma
    return doc


@pytest.mark.netns
def test_agent_process_flies_a_whole_mission_over_tcp(
    netns: NetNamespace, probe: Probe, emulator: EmulatorProcess, tmp_path: Path
) -> None:
    doc = process_doc("sitl", f"tcp:127.0.0.1:{emulator.tcp_port}", _bma(rtl_after=3.0))
    agent = AgentProcesses(netns, tmp_path, doc)
    agent.start("agent")
    try:
        for state in (M.STANDBY, M.TAKEOFF, M.MISSION):
            assert probe.wait("sitl/MC_STATE", "mc_state_t", timeout=15, state=state), (
                f"never reached {state}"
            )
        # (velocity commands are internal to `antalate agent` now: they travel in memory, and the
        # separate-process test below sends them over multicast)
        mark = probe.mark()
        assert probe.wait("sitl/MC_STATE", "mc_state_t", timeout=10, since=mark, state=M.RTL)
        mark = probe.mark()
        assert probe.wait("sitl/MC_STATE", "mc_state_t", timeout=20, since=mark, state=M.STANDBY)
        down = probe.wait("sitl/TELEMETRY", "telemetry_t", since=mark, timeout=2, armed=False, in_air=False)
        assert down is not None and down["mode"] == "RTL" and down["alt"] == 0.0
        ready = probe.wait("sitl/HLC_STATE", "hlc_state_t", since=mark, state=H.READY)
        assert ready is not None and ready["autopilot"] == "mavlink"
        assert agent.alive("agent")
    finally:
        codes = agent.stop()
    final = emulator.stop()
    assert not final["armed"] and final["alt"] == 0.0
    assert (
        math.hypot(final["north"], final["east"]) < 1.0
    )  # RTL brought it home (the emulator overshoots a little)
    assert codes["agent"] in (0, -15), codes
    log = agent.log("agent")
    assert "connected to autopilot (1, 1)" in log and "mode GUIDED confirmed" in log


def take_off(probe: Probe) -> None:
    """The operator's TAKEOFF once the agent's MC is in STANDBY; the MC must reach MISSION."""
    assert probe.wait("copter/MC_STATE", "mc_state_t", timeout=15, state=M.STANDBY)
    probe.publish(
        "copter/OPERATOR_CMD", "operator_cmd_t", header={"seq": 1, "agent": "op"}, command=O.TAKEOFF
    )
    assert probe.wait("copter/MC_STATE", "mc_state_t", timeout=15, state=M.MISSION)


def fly_east(probe: Probe) -> None:
    """Velocity commands east at 3 m/s for a second, as the agent's BMA would send them (an internal topic:
    the sender must be the agent the channel names); the copter's telemetry must show it moving east."""
    moving = probe.mark()
    for i in range(10):
        probe.publish(
            "copter/VELOCITY_CMD",
            "velocity_cmd_t",
            header={"seq": i + 1, "agent": "copter"},
            frame=1,
            vx=0.0,
            vy=3.0,
        )
        time.sleep(0.1)
    east = [t["ve"] for t in probe.history("copter/TELEMETRY", "telemetry_t", since=moving)]
    assert max(east) > 2.0, east


@pytest.mark.netns
def test_hlc_restart_mid_flight_resyncs_without_arming_or_taking_off(
    netns: NetNamespace, probe: Probe, emulator: EmulatorProcess, tmp_path: Path
) -> None:
    doc = process_doc("copter", f"udpout:127.0.0.1:{emulator.udp_port}")
    # The restart is what is tested, not the MC's watchdog: a restarted HLC on a loaded machine takes more
    # than the 1 s the MC's default 2 s leaves it (Python, pymavlink, the link) and HLC_LOST would come first.
    doc["mc"] = {"hlc_timeout": 10.0}
    agent = AgentProcesses(netns, tmp_path, doc)
    agent.start("hlc")
    agent.start("mc")
    try:
        take_off(probe)
        assert "autopilot ARM" in agent.log("hlc")
        agent.kill("hlc")  # SIGKILL: the real vehicle flies on, hovering in GUIDED
        time.sleep(1.0)
        mark = probe.mark()
        agent.start("hlc")
        assert probe.wait("copter/HLC_STATE", "hlc_state_t", timeout=15, since=mark, state=H.AIRBORNE)
        log = agent.log("hlc")
        assert "INIT -> AIRBORNE" in log
        assert "autopilot ARM" not in log and "autopilot TAKEOFF" not in log
        assert {m["state"] for m in probe.history("copter/MC_STATE", "mc_state_t", since=mark)} == {M.MISSION}
        airborne = probe.wait("copter/TELEMETRY", "telemetry_t", since=mark, timeout=5, in_air=True)
        assert airborne is not None and airborne["alt"] > 2.0 and airborne["mode"] == "GUIDED"
        # velocity commands reach the copter through the restarted HLC: east at 3 m/s for a second
        fly_east(probe)
        # and it still obeys: RTL brings it home and down
        probe.publish(
            "copter/OPERATOR_CMD", "operator_cmd_t", header={"seq": 2, "agent": "op"}, command=O.RTL
        )
        assert probe.wait("copter/MC_STATE", "mc_state_t", timeout=10, since=mark, state=M.RTL)
        assert probe.wait("copter/MC_STATE", "mc_state_t", timeout=20, since=probe.mark(), state=M.STANDBY)
    finally:
        codes = agent.stop()
    final = emulator.stop()
    assert not final["armed"] and final["alt"] == 0.0
    assert all(c in (0, -15, None) for c in codes.values()), codes


@pytest.mark.netns
def test_hlc_killed_the_vehicle_stops_and_comes_home_by_its_gcs_failsafe(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    """The vehicle set up as docs/ardupilot.md says; the HLC process dies while it flies east."""
    emulator = EmulatorProcess(
        netns,
        "--param",
        "FS_GCS_ENABLE=1",
        "--param",
        "SYSID_MYGCS=245",
        "--param",
        "FS_GCS_TIMEOUT=2",
        "--param",
        "GUID_TIMEOUT=1",
        "--param",
        "FENCE_ENABLE=1",
        "--param",
        "BATT_FS_LOW_ACT=2",
    )
    doc = process_doc("copter", f"udpout:127.0.0.1:{emulator.udp_port}")
    doc["hlc"]["autopilot_params"]["require_vehicle_failsafes"] = True
    agent = AgentProcesses(netns, tmp_path, doc)
    agent.start("hlc")
    agent.start("mc")
    try:
        take_off(probe)
        assert "vehicle pre-flight check: failsafe parameters OK" in agent.log("hlc")
        fly_east(probe)
        agent.kill("hlc")  # SIGKILL while flying east: no LAND, no RTL, nothing more on the link
        time.sleep(1.0 + 2.0 + 6.0)  # GUID_TIMEOUT, FS_GCS_TIMEOUT, then the RTL home and the landing
    finally:
        agent.stop()
        final = (
            emulator.stop()
        )  # the vehicle's own record (tests/vehicles/test_mavlink_failsafes.py times the stop)
    assert ["GCS failsafe", "RTL"] in final["failsafe_modes"] and "GCS Failsafe" in final["statustexts"]
    assert not final["armed"] and final["alt"] == 0.0
    assert math.hypot(final["north"], final["east"]) < 1.0
