"""`CrazyflieAdapter` through the real cflib against the Crazyflie emulator, without the HLC.

Each test reads the emulated vehicle (its true state) and the adapter's `state()`: arming refusals
with their reasons, velocities the right way and speed in both frames, the hand-back to the
high-level commander, link loss, RTL, and the emergency stop on close in the air.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

pytest.importorskip("cflib")

from antalate_lcm.base.geo import distance  # noqa: E402
from antalate_lcm.vehicles.base import AutopilotError, Frame  # noqa: E402
from antalate_lcm.vehicles.crazyflie import CFLIB_MISSING, CrazyflieAdapter  # noqa: E402
from tests.emulators.crazyflie_emulator import CrazyflieEmulator  # noqa: E402
from tests.emulators.crazyradio import Crazyradio, install  # noqa: E402
from tests.harness.polling import wait_for  # noqa: E402

FAST = {"climb_speed": 2.0, "land_speed": 1.0, "rtl_speed": 2.0, "connect_timeout": 5.0}


@pytest.fixture
def rig() -> Iterator[Callable[..., tuple[CrazyflieEmulator, CrazyflieAdapter]]]:
    made: list[tuple[CrazyflieEmulator, CrazyflieAdapter]] = []

    def make(emu: dict[str, Any] | None = None, **params: Any) -> tuple[CrazyflieEmulator, CrazyflieAdapter]:
        e = CrazyflieEmulator(**(emu or {})).start()
        ap = CrazyflieAdapter({"uri": e.uri, **FAST, **params})
        made.append((e, ap))
        ap.connect()
        return e, ap

    yield make
    for e, ap in made:
        ap.close()
        e.stop()


@pytest.fixture
def radio_rig() -> Iterator[Callable[..., tuple[CrazyflieEmulator, CrazyflieAdapter, Crazyradio]]]:
    """The emulator behind an emulated Crazyradio dongle: cflib's own radio:// driver, acks and all."""
    dongle = Crazyradio()
    uninstall = install(dongle)
    made: list[tuple[CrazyflieEmulator, CrazyflieAdapter]] = []

    def make(**params: Any) -> tuple[CrazyflieEmulator, CrazyflieAdapter, Crazyradio]:
        e = CrazyflieEmulator(radio=True).start()
        ap = CrazyflieAdapter({"uri": dongle.add(e), **FAST, **params})
        made.append((e, ap))
        ap.connect()
        return e, ap, dongle

    yield make
    for e, ap in made:
        ap.close()
        e.stop()
    uninstall()


def airborne(emu: CrazyflieEmulator, ap: CrazyflieAdapter, alt: float = 1.0) -> None:
    # arm() refuses until the estimator's variances have come in their log block (its first period)
    assert wait_for(ap.arm, timeout=2.0, interval=0.05), ap.last_refusal
    ap.takeoff(alt)
    assert wait_for(lambda: ap.state().alt >= 0.98 * alt and emu.snapshot().hl_kind == "hold")


def test_state_maps_the_local_pose_to_wgs84_and_ned(rig: Callable[..., Any]) -> None:
    emu, ap = rig({"x": 3.0, "y": 4.0, "yaw": 90.0}, origin_heading=90.0)
    s = ap.state()
    assert s.connected and s.link_age < 0.5
    # +x is east, +y north: (3, 4) is 3 m east and 4 m north; yaw 90 (anticlockwise) faces north
    assert distance(32.7767, 35.0231, s.lat, s.lon) == pytest.approx(5.0, abs=0.01)
    assert s.heading == pytest.approx(0.0, abs=0.1)
    assert s.voltage == pytest.approx(4.1, abs=1e-3) and s.cells == 1 and s.battery == 90.0
    assert not s.armed and not s.in_air and s.landed


def test_arm_is_refused_until_the_estimator_converges(rig: Callable[..., Any]) -> None:
    emu, ap = rig({"converged": False})
    assert ap.arm() is False
    assert "not converged" in ap.last_refusal and "varX" in ap.last_refusal
    assert not emu.snapshot().armed
    emu.set_converged(True)
    assert wait_for(lambda: ap.arm())
    assert emu.snapshot().armed and ap.last_refusal == ""


def test_arm_is_refused_by_a_locked_supervisor_with_what_to_do(rig: Callable[..., Any]) -> None:
    emu, ap = rig({"locked": True})
    assert ap.arm() is False
    assert "locked" in ap.last_refusal and "reboot" in ap.last_refusal
    with pytest.raises(AutopilotError, match="not armed"):
        ap.takeoff(1.0)
    assert emu.snapshot().z == 0.0


def test_arm_is_refused_below_the_low_voltage_before_the_firmware_says_low_power(
    rig: Callable[..., Any],
) -> None:
    """pm_stm32f4.c says lowPower only after 5 s below 3.2 V: the adapter refuses at once by pm.vbat.
    (It used to wait for pm.state, which the emulator set at once; the firmware does not.)"""
    emu, ap = rig({"voltage": 3.1})
    assert ap.arm() is False
    assert "battery low" in ap.last_refusal and "3.10 V <= low_voltage 3.2 V" in ap.last_refusal
    assert emu.pm_state == 0 and not ap.state().battery_warning  # the firmware's verdict is 5 s away


def test_ned_velocity_moves_the_vehicle_north_at_the_commanded_speed(rig: Callable[..., Any]) -> None:
    emu, ap = rig(origin_heading=90.0)  # +x east, +y north
    airborne(emu, ap)
    for _ in range(20):
        ap.set_velocity(0.6, 0.0, 0.0, 0.0, Frame.NED)
        time.sleep(0.05)
    snap = emu.snapshot()
    assert snap.streaming
    assert snap.vy == pytest.approx(0.6, abs=0.05) and abs(snap.vx) < 0.05  # north is +y
    s = ap.state()
    assert s.vn == pytest.approx(0.6, abs=0.05) and abs(s.ve) < 0.05
    assert s.alt == pytest.approx(1.0, abs=0.05)


def test_body_velocity_follows_the_heading_and_climbs(rig: Callable[..., Any]) -> None:
    emu, ap = rig({"yaw": 90.0})  # origin heading 0: the vehicle faces west (+y)
    airborne(emu, ap)
    assert ap.state().heading == pytest.approx(270.0, abs=0.5)
    for _ in range(20):
        ap.set_velocity(0.5, 0.0, -0.3, 0.0, Frame.BODY)  # forward, climbing 0.3 m/s
        time.sleep(0.05)
    s = ap.state()
    assert s.ve == pytest.approx(-0.5, abs=0.08) and abs(s.vn) < 0.08  # forward is west
    assert s.alt > 1.15  # 1 s at 0.3 m/s, behind by the vertical response


def test_an_unrenewed_velocity_hands_back_to_the_high_level_commander(rig: Callable[..., Any]) -> None:
    emu, ap = rig()
    airborne(emu, ap)
    ap.set_velocity(0.5, 0.0, 0.0, 0.0, Frame.NED)
    assert wait_for(lambda: emu.snapshot().streaming)
    assert wait_for(lambda: not emu.snapshot().streaming, timeout=3.0)  # velocity_hold, then notify stop
    assert emu.notify_stops >= 1 and emu.hl_commands[-1][0] == "goto"
    time.sleep(2.5)  # past the firmware watchdog: under the high-level commander it keeps flying
    assert emu.snapshot().flying and not emu.snapshot().locked


def test_rtl_flies_to_the_takeoff_point_and_lands_disarmed(rig: Callable[..., Any]) -> None:
    emu, ap = rig({"x": 1.0, "y": 2.0})
    airborne(emu, ap)
    for _ in range(20):
        ap.set_velocity(1.0, 1.0, 0.0, 0.0, Frame.NED)
        time.sleep(0.05)
    assert math.hypot(emu.snapshot().x - 1.0, emu.snapshot().y - 2.0) > 1.0
    ap.rtl()
    assert ap.state().mode == "RTL"
    assert wait_for(lambda: ap.state().landed, timeout=15.0)
    snap = emu.snapshot()
    assert math.hypot(snap.x - 1.0, snap.y - 2.0) <= 0.15 and snap.z == 0.0 and not snap.flying
    # the adapter disarmed it; a CF2.x arms itself again (auto-arming), which the HLC must not see
    assert wait_for(lambda: emu.snapshot().armed)
    assert not ap.state().armed and ap.state().landed


def test_link_loss_holds_then_lands_blindly_and_says_so(rig: Callable[..., Any]) -> None:
    emu, ap = rig(link_loss_land=1.0)
    airborne(emu, ap)
    emu.set_silent(True)
    assert wait_for(lambda: ap.state().link_age > 1.2)
    assert emu.snapshot().flying  # hovering under the high-level commander
    emu.set_silent(False)  # the link comes back: the landing sent blindly is repeated until it arrives
    assert wait_for(lambda: emu.snapshot().hl_kind == "land" or not emu.snapshot().flying, timeout=5.0)
    s = ap.state()
    assert s.mode in ("LAND", "IDLE")
    assert wait_for(lambda: ap.state().landed, timeout=10.0)


def test_landing_failsafe_is_reported_while_it_lands(rig: Callable[..., Any]) -> None:
    emu, ap = rig({"velocity_tau": 0.1}, link_loss_land=0.8, land_speed=0.2)
    airborne(emu, ap)
    emu.set_silent(True)
    assert wait_for(lambda: ap.state().flight_mode.name == "LANDING")
    assert "link lost" in ap.state().failsafe
    emu.set_silent(False)


def test_close_in_the_air_is_an_emergency_stop(rig: Callable[..., Any]) -> None:
    emu, ap = rig()
    airborne(emu, ap)
    ap.close()
    assert wait_for(lambda: emu.emergency_stops >= 1)
    snap = emu.snapshot()
    assert not snap.flying and snap.locked


def test_velocity_on_the_ground_is_refused(rig: Callable[..., Any]) -> None:
    emu, ap = rig()
    with pytest.raises(AutopilotError, match="not flying"):
        ap.set_velocity(0.5, 0.0, 0.0, 0.0, Frame.NED)
    assert emu.setpoints == 0


def test_without_cflib_connect_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "cflib", None)
    ap = CrazyflieAdapter({"uri": "udp://127.0.0.1:9"})
    with pytest.raises(AutopilotError) as err:
        ap.connect()
    assert str(err.value) == CFLIB_MISSING and "antalate[crazyflie]" in str(err.value)


def test_nobody_answering_fails_connect_within_its_timeout() -> None:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))  # a port that swallows everything
        ap = CrazyflieAdapter({"uri": f"udp://127.0.0.1:{s.getsockname()[1]}", "connect_timeout": 1.0})
        with pytest.raises(AutopilotError, match="cannot connect"):
            ap.connect()
        ap.close()


def test_a_link_cflib_gives_up_on_is_reopened(rig: Callable[..., Any]) -> None:
    """cflib's radio driver closes the link after a run of lost packets; the adapter reopens it."""
    emu, ap = rig(connect_timeout=1.5)
    airborne(emu, ap)
    emu.set_silent(True)
    ap._cf._link_error_cb("Too many packets lost")  # what cflib's RadioDriver calls; the link closes
    assert wait_for(lambda: not ap.state().connected)
    with pytest.raises(AutopilotError, match="not connected.*Too many packets lost"):
        ap.land()
    time.sleep(1.0)  # the first reopening (at once) fails while the Crazyflie is silent
    assert ap.reconnects == 0
    emu.set_silent(False)
    assert wait_for(lambda: ap.state().connected and ap.state().link_age < 0.5, timeout=15.0)
    assert ap.reconnects == 1 and ap.state().in_air
    ap.land()  # commands work again on the new link
    assert wait_for(lambda: ap.state().landed, timeout=10.0)


def test_a_failed_reconnection_never_drops_a_flying_crazyflie(rig: Callable[..., Any]) -> None:
    """A reopening attempt that times out as the radio returns closes its link without zero thrust."""
    emu, ap = rig(connect_timeout=1.0)
    airborne(emu, ap)
    emu.set_silent(True)
    ap._cf._link_error_cb("Too many packets lost")  # the old link is closed: no more pings
    time.sleep(0.3)
    before = emu.dropped
    assert wait_for(lambda: emu.dropped > before)  # the first attempt's request is lost: it will time out
    emu.set_silent(False)  # the radio is back as it gives up: its close reaches the vehicle
    assert wait_for(lambda: ap.reconnects >= 1 and ap.state().connected, timeout=10.0)
    assert emu.snapshot().flying and emu.snapshot().z > 0.9


# --------------------------------------------------------------------------- the firmware's own rules
# (crazyflie-firmware 2026.08, cflib 0.1.34; tests/emulators/crazyflie_emulator.py cites each file)


def test_a_lost_command_after_notify_setpoint_stop_never_drops_the_crazyflie(rig: Callable[..., Any]) -> None:
    """PR #1298: notify-stop with no high-level command after it is motors off. The adapter sends
    command, notify, command, and resends until the firmware answers: one lost command changes nothing."""
    emu, ap = rig()
    airborne(emu, ap)
    for _ in range(6):
        ap.set_velocity(0.5, 0.0, 0.0, 0.0, Frame.NED)
        time.sleep(0.05)
    assert emu.snapshot().streaming
    emu.drop_next(8)  # the first high-level packet of the hand-back is lost
    ap.set_velocity(0.0, 0.0, 0.0, 0.0, Frame.NED)  # zero velocity: hold
    assert wait_for(lambda: not emu.snapshot().streaming)
    time.sleep(2.5)  # past the watchdog and any fall
    snap = emu.snapshot()
    assert snap.flying and snap.z > 0.9 and emu.falls == 0 and not snap.locked
    assert emu.notify_stops >= 1 and ap.state().mode == "HL_HOLD"


def test_a_stale_link_hold_is_resent_until_it_arrives(rig: Callable[..., Any]) -> None:
    """The link goes silent mid-stream: the hold (command, notify, command) is lost, the firmware's
    watchdog levels the vehicle and keeps its climb (supervisor.c); once the link is back within the
    2 s cut the unanswered hold is resent, and the Crazyflie holds instead of falling."""
    emu, ap = rig(link_stale_after=0.3)
    airborne(emu, ap)
    for _ in range(6):
        ap.set_velocity(0.0, 0.0, -0.3, 0.0, Frame.NED)  # climbing 0.3 m/s
        time.sleep(0.05)
    emu.set_silent(True)
    t0 = time.monotonic()
    assert wait_for(lambda: ap.state().mode == "HL_HOLD", timeout=2.0)  # decided, sent into the void
    time.sleep(max(0.0, t0 + 1.0 - time.monotonic()))
    z_silent = emu.snapshot().z
    assert emu.snapshot().vz > 0.2  # the watchdog's level-out: the climb goes on
    emu.set_silent(False)  # 1 s in: before the 2 s cut
    assert wait_for(lambda: emu.snapshot().hl_kind in ("goto", "hold"), timeout=1.5)
    time.sleep(2.0)
    snap = emu.snapshot()
    assert snap.flying and not snap.locked and emu.falls == 0
    assert snap.z >= z_silent and abs(snap.vz) < 0.05  # held where it got to, no longer climbing


def test_cflib_closing_the_link_in_a_hover_still_lands_blindly_once_reopened(
    radio_rig: Callable[..., Any],
) -> None:
    """Over cflib's radio:// driver: the Crazyflie's radio goes silent, the driver resends until 100
    packets went unacknowledged (radiodriver.py) and closes the link. The adapter's loop keeps its
    timers while it reopens the link: link_loss_land decides the landing (the operator sees LANDING,
    "link lost"), and it goes out on the new link; the firmware lands (answered 0)."""
    emu, ap, dongle = radio_rig(link_loss_land=1.0)
    airborne(emu, ap)
    emu.set_silent(True)
    t0 = time.monotonic()
    assert wait_for(lambda: not ap.state().connected, timeout=3.0)
    assert dongle.lost >= 100 and time.monotonic() - t0 < 2.0  # cflib gave up, as on a radio
    assert wait_for(lambda: ap.state().flight_mode.name == "LANDING", timeout=3.0)
    assert "link lost" in ap.state().failsafe
    with pytest.raises(AutopilotError, match="not connected.*Too many packets lost"):
        ap.land()
    assert emu.snapshot().flying  # hovering under the high-level commander meanwhile
    emu.set_silent(False)
    assert wait_for(lambda: ap.state().connected, timeout=10.0)
    assert wait_for(lambda: ("land", 0) in emu.hl_answers, timeout=3.0)  # sent on the new link
    assert wait_for(lambda: ap.state().landed, timeout=10.0)
    assert emu.falls == 0 and ap.reconnects >= 1


def test_cflib_closing_the_link_mid_stream_turns_the_stream_into_a_hold(
    radio_rig: Callable[..., Any],
) -> None:
    """The same closed radio link while streaming: the adapter turns the stream into a hold (HL_HOLD)
    and then a blind landing, to be sent when the link reopens; nothing gets through meanwhile, so the
    firmware's watchdog levels the vehicle at 0.5 s and cuts it at 2 s (supervisor.c). On the new link
    the adapter reads it down and locked and says so (mode LOCKED)."""
    emu, ap, _ = radio_rig(link_loss_land=2.5)
    airborne(emu, ap)
    for _ in range(6):
        ap.set_velocity(0.3, 0.0, 0.0, 0.0, Frame.NED)
        time.sleep(0.05)
    emu.set_silent(True)
    assert wait_for(lambda: not ap.state().connected, timeout=3.0)
    assert wait_for(lambda: ap.state().mode == "HL_HOLD", timeout=1.0)
    assert wait_for(lambda: ap.state().flight_mode.name == "LANDING", timeout=4.0)
    emu.set_silent(False)
    assert wait_for(lambda: ap.state().connected, timeout=10.0)
    assert emu.snapshot().locked and emu.falls == 1  # the outage outlasted the watchdog's 2 s
    # on the new link the adapter sees it down and locked: nothing more is sent, the HLC is told
    assert wait_for(lambda: ap.state().mode == "LOCKED" and ap.state().landed, timeout=5.0)


def test_the_takeoff_needs_arm_although_the_crazyflie_armed_itself(rig: Callable[..., Any]) -> None:
    """MOTORS_REQUIRE_ARMING=n: the supervisor arms at power-on and after every landing. The HLC sees
    disarmed until arm(), and a take-off without it is refused."""
    emu, ap = rig()
    assert wait_for(lambda: emu.snapshot().armed)  # armed itself
    time.sleep(0.3)  # several log periods: the adapter has read the supervisor's "armed" bit
    assert not ap.state().armed
    with pytest.raises(AutopilotError, match="not armed"):
        ap.takeoff(1.0)
    assert emu.snapshot().z == 0.0 and emu.hl_commands == []
    airborne(emu, ap, 0.5)
    ap.land()
    assert wait_for(lambda: ap.state().landed, timeout=10.0)
    assert wait_for(lambda: emu.snapshot().armed)  # re-armed itself after the adapter's disarm
    time.sleep(0.3)
    assert not ap.state().armed
    with pytest.raises(AutopilotError, match="not armed"):
        ap.takeoff(1.0)


def test_a_critical_battery_lands_before_the_firmware_powers_off(rig: Callable[..., Any]) -> None:
    """pm_stm32f4.c: 5 s below 3.0 V in lowPower powers an auto-shutdown build off (it falls). The
    adapter lands where it is once pm.vbat stays below critical_voltage, well inside those 5 s."""
    emu, ap = rig({"auto_shutdown": True}, land_speed=0.5)
    airborne(emu, ap, 0.8)
    emu.set_battery(3.1)
    time.sleep(0.5)
    assert ap.state().in_air and ap.state().flight_mode.name != "LANDING"  # low, not critical
    emu.set_battery(2.95)
    t0 = time.monotonic()
    assert wait_for(lambda: ap.state().flight_mode.name == "LANDING", timeout=2.0)
    assert "battery critical" in ap.state().failsafe
    assert wait_for(lambda: not emu.snapshot().flying, timeout=5.0)
    assert time.monotonic() - t0 < 4.5 and emu.falls == 0  # down by landing, before any shutdown


def test_a_takeoff_the_firmware_refuses_is_reported_with_its_reason(rig: Callable[..., Any]) -> None:
    """stabilizer.c crtpCommanderBlock(!canFly): EBUSY, answered at once instead of a silent timeout."""
    emu, ap = rig(takeoff_confirm=5.0)
    assert ap.arm()
    emu.set_locked(True)  # locked after the arm: the supervisor cannot fly
    t0 = time.monotonic()
    with pytest.raises(AutopilotError, match="EBUSY"):
        ap.takeoff(1.0)
    assert time.monotonic() - t0 < 2.0 and emu.snapshot().z == 0.0


def test_a_takeoff_while_flying_or_landing_is_refused_and_what_it_was_doing_goes_on(
    rig: Callable[..., Any],
) -> None:
    """planner.c plan_takeoff refuses unless its planner is idle (a hover's trajectory, a landing): the
    adapter says so instead of reading the flying bit as a take-off done, and the hold or the landing
    goes on (the landing still ends disarmed)."""
    emu, ap = rig(land_speed=0.5)
    airborne(emu, ap, 0.8)
    mode = ap.state().mode
    with pytest.raises(AutopilotError, match="flying .*land first"):
        ap.takeoff(1.5)
    assert ap.state().mode == mode and emu.snapshot().hl_kind == "hold"
    ap.land()
    assert wait_for(lambda: emu.snapshot().hl_kind == "land")
    with pytest.raises(AutopilotError, match="flying .*land first"):
        ap.takeoff(1.5)
    assert ap.state().flight_mode.name == "LANDING"
    assert [name for name, _ in emu.hl_commands].count("takeoff") == 1
    assert wait_for(lambda: ap.state().landed and not ap.state().armed, timeout=6.0)
    assert emu.falls == 0
