"""The Crazyflie emulator driven by cflib itself: connection, TOCs and their CRC, log streaming, params,
the commanders' priority rule (PR #1298: notify-stop alone stops the motors), the high-level
commander's answers and refusals, the commander watchdog's level-out and cut, auto-arming, and the
battery's low-power and shutdown timers -- each as the firmware source says (2026.08)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("cflib")

import cflib.crtp  # noqa: E402
from cflib.crazyflie import Crazyflie  # noqa: E402
from cflib.crazyflie.log import LogConfig  # noqa: E402
from cflib.crazyflie.syncCrazyflie import SyncCrazyflie  # noqa: E402

from tests.emulators.crazyflie_emulator import CrazyflieEmulator, battery_level  # noqa: E402
from tests.harness.polling import wait_for  # noqa: E402

cflib.crtp.init_drivers() if not cflib.crtp.CLASSES else None


@pytest.fixture
def emu() -> Iterator[CrazyflieEmulator]:
    with CrazyflieEmulator() as e:
        yield e


@pytest.fixture
def scf(emu: CrazyflieEmulator) -> Iterator[SyncCrazyflie]:
    """cflib's SyncCrazyflie on the emulator, every parameter read; closed after the test (`close`)."""
    linked = connect(emu)
    yield linked
    close(linked)


def connect(emu: CrazyflieEmulator, cache: Path | None = None) -> SyncCrazyflie:
    scf = SyncCrazyflie(emu.uri, cf=Crazyflie(rw_cache=str(cache) if cache else None))
    scf.open_link()
    assert scf.is_link_open()
    assert scf.cf.param.get_value("stabilizer.estimator", timeout=5) == "2"  # every param read
    return scf


def close(scf: SyncCrazyflie) -> None:
    """Close like the adapter does: cflib's 10 Hz latency pings stopped first. cflib closes the
    driver before it stops them, so a ping sent in between fails on the closed socket, and its link
    error callback then joins the ping thread from that same thread (a RuntimeError in the thread)."""
    scf.cf.link_statistics.stop()
    scf.close_link()


def stream(
    scf: SyncCrazyflie, names: list[str], period_ms: int = 50
) -> tuple[list[tuple[int, dict[str, Any]]], LogConfig]:
    got: list[tuple[int, dict[str, Any]]] = []
    lock = threading.Lock()
    config = LogConfig("test", period_ms)
    for name in names:
        config.add_variable(name)
    scf.cf.log.add_config(config)

    def on_data(ts: int, data: dict[str, Any], _c: Any) -> None:
        with lock:
            got.append((ts, dict(data)))

    config.data_received_cb.add_callback(on_data)
    config.start()
    return got, config


def test_cflib_reads_both_tocs_and_caches_them_under_the_firmware_crc(
    emu: CrazyflieEmulator, tmp_path: Path
) -> None:
    scf = connect(emu, tmp_path)
    try:
        toc = scf.cf.log.toc.toc
        assert set(toc["stateEstimate"]) >= {"x", "y", "z", "vx", "vy", "vz", "yaw"}
        assert toc["pm"]["vbat"].ctype == "float" and toc["pm"]["state"].ctype == "int8_t"
        assert toc["supervisor"]["info"].ctype == "uint16_t"
        assert scf.cf.param.toc.toc["commander"]["enHighLevel"].ctype == "uint8_t"
    finally:
        close(scf)
    # cflib files each TOC under the CRC the firmware sent: both are there, named by our CRCs
    names = {p.name for p in tmp_path.glob("*.json")}
    assert names == {f"{emu.log_crc:08X}.json", f"{emu.param_crc:08X}.json"}
    cached = json.loads((tmp_path / f"{emu.log_crc:08X}.json").read_text())
    assert "stateEstimate" in cached


def test_the_crc_changes_with_the_toc(emu: CrazyflieEmulator) -> None:
    from tests.emulators.crazyflie_emulator import LOG_GROUP, LOG_START, TocEntry, toc_crc

    entries = list(emu.log_entries)
    assert toc_crc(entries) == emu.log_crc
    renamed = [TocEntry(e.type, e.name + "2", e.group) if e.name == "vbat" else e for e in entries]
    assert toc_crc(renamed) != emu.log_crc
    # group markers count: moving a variable to another group changes the CRC even with the same names
    assert entries[0] == TocEntry(LOG_GROUP | LOG_START, "stateEstimate")


def test_log_block_streams_values_at_its_period(emu: CrazyflieEmulator, scf: SyncCrazyflie) -> None:
    got, _ = stream(scf, ["stateEstimate.z", "pm.vbat", "pm.batteryLevel", "supervisor.info"], period_ms=100)
    assert wait_for(lambda: len(got) >= 12)
    stamps = [ts for ts, _ in got[:12]]
    gaps = sorted(b - a for a, b in zip(stamps, stamps[1:], strict=False))
    # the firmware's ms timestamps, one period apart (the median: a loaded host may stall one send)
    assert 90 <= gaps[len(gaps) // 2] <= 110, gaps
    data = got[-1][1]
    assert data["pm.vbat"] == pytest.approx(4.1, abs=1e-6) and data["pm.batteryLevel"] == 90


def test_param_write_is_echoed_and_applied(emu: CrazyflieEmulator, scf: SyncCrazyflie) -> None:
    scf.cf.param.set_value("kalman.resetEstimation", 1)
    assert wait_for(lambda: emu.params["kalman.resetEstimation"] == 1)
    assert wait_for(lambda: scf.cf.param.values["kalman"]["resetEstimation"] == "1")


def airborne(emu: CrazyflieEmulator, cf: Crazyflie, height: float = 1.0) -> None:
    """Take off with cflib (the emulator armed itself: auto-arming) and wait for the hover."""
    assert wait_for(lambda: emu.snapshot().armed)
    cf.high_level_commander.takeoff(height, 1.0)
    assert wait_for(lambda: emu.snapshot().z > height - 0.05 and emu.snapshot().hl_kind == "hold")


def test_a_streamed_setpoint_outranks_the_planner_until_notify_setpoint_stop(
    emu: CrazyflieEmulator, scf: SyncCrazyflie
) -> None:
    """commander.c: the stream has priority; a land sent meanwhile is planned but not flown until the
    notification relaxes the priority; a second land while landing is refused (planner.c)."""
    cf = scf.cf
    airborne(emu, cf)
    for _ in range(10):
        cf.commander.send_velocity_world_setpoint(0.5, 0.0, 0.0, 0.0)
        time.sleep(0.05)
    assert emu.snapshot().streaming and emu.snapshot().vx > 0.3
    cf.high_level_commander.land(0.0, 1.0)  # planned, answered 0, but the stream still flies
    assert wait_for(lambda: ("land", 0) in emu.hl_answers)
    snap = emu.snapshot()
    assert snap.streaming and snap.z > 0.95
    cf.commander.send_notify_setpoint_stop()
    cf.high_level_commander.land(0.0, 1.0)  # already landing: refused, and answered so
    assert wait_for(lambda: emu.hl_answers[-1] == ("land", 1))
    assert wait_for(lambda: not emu.snapshot().flying)
    assert emu.notify_stops == 1 and emu.falls == 0


def test_notify_setpoint_stop_alone_stops_the_motors(emu: CrazyflieEmulator, scf: SyncCrazyflie) -> None:
    """PR #1298: the stream stopped the planner, so after the notification it sends the null set-point:
    a Crazyflie that gets no high-level command next falls; one that does, holds where it is."""
    cf = scf.cf
    airborne(emu, cf)
    for _ in range(5):
        cf.commander.send_hover_setpoint(0.0, 0.0, 0.0, 1.0)
        time.sleep(0.05)
    cf.commander.send_notify_setpoint_stop()
    cf.high_level_commander.go_to(0.0, 0.0, 0.0, 0.0, 0.5, relative=True)
    time.sleep(0.5)
    assert emu.snapshot().flying and emu.snapshot().z > 0.9 and emu.falls == 0
    cf.commander.send_hover_setpoint(0.0, 0.0, 0.0, 1.0)
    time.sleep(0.1)
    cf.commander.send_notify_setpoint_stop()  # and no high-level command
    assert wait_for(lambda: emu.snapshot().z == 0.0, timeout=3.0)
    assert emu.falls == 1 and not emu.snapshot().flying and not emu.snapshot().locked


def test_every_high_level_packet_is_answered_and_the_planner_refuses_a_second_takeoff(
    emu: CrazyflieEmulator,
) -> None:
    scf = connect(emu)
    cf = scf.cf
    answers: list[list[int]] = []
    cf.add_port_callback(8, lambda pk: answers.append(list(pk.data)))
    try:
        airborne(emu, cf)
        cf.high_level_commander.takeoff(1.5, 1.0)  # flying a trajectory: plan_takeoff refuses
        assert wait_for(lambda: len(answers) >= 2)
        assert answers[0][0] == 7 and answers[0][3] == 0 and answers[1][0] == 7 and answers[1][3] == 1
        time.sleep(0.5)
        assert emu.snapshot().z == pytest.approx(1.0, abs=0.02)
        cf.high_level_commander.go_to(0.5, 0.0, 1.0, 0.0, 1.0)
        assert wait_for(lambda: len(answers) >= 3 and answers[2][0] == 12 and answers[2][3] == 0)
    finally:
        close(scf)


def test_the_watchdog_levels_out_but_keeps_the_vertical_velocity_then_cuts_at_two_seconds(
    emu: CrazyflieEmulator,
    scf: SyncCrazyflie,
) -> None:
    """supervisor.c: after 0.5 s WarningLevelOut (x/y level, z as set: the climb goes on), after 2 s the
    motors stop and the supervisor locks."""
    cf = scf.cf
    airborne(emu, cf)
    for _ in range(10):
        cf.commander.send_velocity_world_setpoint(0.4, 0.0, 0.3, 0.0)
        time.sleep(0.05)
    last = time.monotonic()
    time.sleep(1.0)  # in WarningLevelOut
    snap = emu.snapshot()
    assert snap.flying and snap.vz == pytest.approx(0.3, abs=0.03)  # still climbing
    assert snap.vx == pytest.approx(0.4, abs=0.05)  # level: coasting, not braked
    z_at_1s = snap.z
    time.sleep(max(0.0, last + 1.7 - time.monotonic()))
    assert emu.snapshot().z > z_at_1s + 0.1
    assert wait_for(lambda: not emu.snapshot().flying, timeout=2.0)
    assert time.monotonic() - last >= 1.9  # `last` is 50 ms after the last set-point
    assert emu.snapshot().locked
    assert wait_for(lambda: emu.snapshot().z == 0.0, timeout=2.0) and emu.falls == 1
    got, _ = stream(scf, ["supervisor.info"])
    assert wait_for(lambda: bool(got))
    assert got[-1][1]["supervisor.info"] >> 6 & 1  # locked bit


def test_auto_arming_arms_at_power_on_and_after_every_disarm(emu: CrazyflieEmulator) -> None:
    """Kconfig MOTORS_REQUIRE_ARMING=n (a CF2.x's default): the supervisor arms itself."""
    scf = connect(emu)
    cf = scf.cf
    try:
        assert wait_for(lambda: emu.snapshot().armed)
        cf.supervisor.send_arming_request(False)
        assert wait_for(lambda: any(p == 9 and ch == 1 for p, ch, _ in emu.received))
        assert wait_for(lambda: emu.snapshot().armed)  # re-armed by itself
    finally:
        close(scf)
    with CrazyflieEmulator(auto_arming=False) as e:  # a MOTORS_REQUIRE_ARMING=y build
        time.sleep(0.3)
        assert not e.snapshot().armed


def test_locked_supervisor_refuses_to_arm_and_takeoff_does_nothing(emu: CrazyflieEmulator) -> None:
    emu.set_locked(True)
    scf = connect(emu)
    cf = scf.cf
    try:
        cf.supervisor.send_arming_request(True)
        assert wait_for(lambda: any(p == 9 and ch == 1 for p, ch, _ in emu.received))
        time.sleep(0.2)
        cf.high_level_commander.takeoff(1.0, 1.0)
        assert wait_for(lambda: emu.hl_answers == [("takeoff", 16)])  # EBUSY: crtpCommanderBlock
        time.sleep(0.3)
        snap = emu.snapshot()
        assert not snap.armed and not snap.flying and snap.z == 0.0
    finally:
        close(scf)


@pytest.mark.parametrize(
    ("volts", "level"), [(4.2, 90), (4.05, 90), (3.9, 50), (3.79, 20), (3.5, 10), (2.9, 0)]
)
def test_battery_level_follows_the_firmware_charge_curve(volts: float, level: int) -> None:
    assert battery_level(volts) == level


def test_low_power_comes_five_seconds_below_the_low_voltage_and_a_shutdown_five_after_critical(
    emu: CrazyflieEmulator,
) -> None:
    """pm_stm32f4.c: lowPower after 5 s under 3.2 V; in lowPower, 5 s under 3.0 V shuts an
    auto_shutdown build down (motors off, radio dead); a default build flies on."""
    emu.auto_shutdown = True
    scf = connect(emu)
    cf = scf.cf
    try:
        got, _ = stream(scf, ["pm.vbat", "pm.state"])
        airborne(emu, cf, 0.5)
        emu.set_battery(3.1)  # below 3.2 V: the low timer starts
        below = time.monotonic()
        time.sleep(2.5)
        emu.set_battery(2.95)  # below 3.0 V: the critical timer starts
        critical = time.monotonic()
        assert got[-1][1]["pm.state"] == 0  # not yet: the firmware waits 5 s
        assert wait_for(lambda: got[-1][1]["pm.state"] == 3, timeout=5.0)
        assert time.monotonic() - below > 4.9
        assert not emu.shut_down  # the critical timer runs 5 s of its own
        assert wait_for(lambda: emu.shut_down, timeout=5.0)
        assert time.monotonic() - critical > 4.9
        assert not emu.snapshot().flying
        assert wait_for(lambda: emu.falls == 1)
        n = len(got)
        time.sleep(0.3)
        assert len(got) == n  # powered off: no more log packets
    finally:
        close(scf)
    with CrazyflieEmulator(voltage=2.9) as e:  # a default build (no CONFIG_PM_AUTO_SHUTDOWN)
        assert e.pm_state == 0
        time.sleep(0.2)
        assert not e.shut_down


def test_silence_stops_every_packet_both_ways(emu: CrazyflieEmulator, scf: SyncCrazyflie) -> None:
    got, _ = stream(scf, ["pm.vbat"])
    assert wait_for(lambda: len(got) > 2)
    emu.set_silent(True)
    time.sleep(0.2)
    n, received = len(got), len(emu.received)
    time.sleep(0.5)
    assert len(got) == n and len(emu.received) == received
    emu.set_silent(False)
    assert wait_for(lambda: len(got) > n)


def test_cflib_closing_the_link_in_flight_stops_the_motors(emu: CrazyflieEmulator) -> None:
    """cflib's close_link sends a zero-thrust legacy set-point: why the adapter closes links without it."""
    scf = connect(emu)
    assert wait_for(lambda: emu.snapshot().armed)  # auto-arming
    scf.cf.high_level_commander.takeoff(0.5, 1.0)
    assert wait_for(lambda: emu.snapshot().z > 0.4)
    close(scf)
    assert wait_for(lambda: not emu.snapshot().flying)
    assert wait_for(lambda: emu.snapshot().z == 0.0) and emu.falls == 1  # it falls at 1 g


def test_the_flying_bit_stays_two_seconds_after_the_motors_stop_and_the_landed_timeout_follows() -> None:
    """supervisor.c IS_FLYING_HYSTERESIS_THRESHOLD (2 s), then LANDING_TIMEOUT_MS (3 s) in Landed."""
    now = [100.0]
    emu = CrazyflieEmulator(clock=lambda: now[0], auto_arming=False)
    try:
        emu.armed = emu.motors = True  # spinning on the floor, as at the end of a landing
        emu._step(0.01, now[0])  # noqa: SLF001 - one physics step on a clock of the test's own
        emu._motors_off(now[0])  # noqa: SLF001 - the planner's null set-point
        for t, flying_bit, armed in (
            (1.9, True, True),
            (2.1, False, True),
            (4.9, False, True),
            (5.1, False, False),
        ):
            now[0] = 100.0 + t
            emu._step(0.01, now[0])  # noqa: SLF001
            assert not emu.flying and emu.flying_bit() == flying_bit and emu.armed == armed, t
            assert bool(emu.supervisor_info() & 1 << 4) == flying_bit  # the bitfield's "is flying"
    finally:
        emu.stop()
