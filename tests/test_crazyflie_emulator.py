"""The Crazyflie emulator driven by cflib itself: connection, TOCs and their CRC, log streaming, params,
the commanders' priority rule, the commander watchdog, the supervisor and the battery."""

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
from tests.polling import wait_for  # noqa: E402

cflib.crtp.init_drivers() if not cflib.crtp.CLASSES else None


@pytest.fixture
def emu() -> Iterator[CrazyflieEmulator]:
    with CrazyflieEmulator() as e:
        yield e


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


def test_log_block_streams_values_at_its_period(emu: CrazyflieEmulator) -> None:
    scf = connect(emu)
    try:
        got, _ = stream(
            scf, ["stateEstimate.z", "pm.vbat", "pm.batteryLevel", "supervisor.info"], period_ms=100
        )
        assert wait_for(lambda: len(got) >= 12)
        stamps = [ts for ts, _ in got[:12]]
        gaps = sorted(b - a for a, b in zip(stamps, stamps[1:], strict=False))
        # the firmware's ms timestamps, one period apart (the median: a loaded host may stall one send)
        assert 90 <= gaps[len(gaps) // 2] <= 110, gaps
        data = got[-1][1]
        assert data["pm.vbat"] == pytest.approx(4.1, abs=1e-6) and data["pm.batteryLevel"] == 90
    finally:
        close(scf)


def test_param_write_is_echoed_and_applied(emu: CrazyflieEmulator) -> None:
    scf = connect(emu)
    try:
        scf.cf.param.set_value("kalman.resetEstimation", 1)
        assert wait_for(lambda: emu.params["kalman.resetEstimation"] == 1)
        assert wait_for(lambda: scf.cf.param.values["kalman"]["resetEstimation"] == "1")
    finally:
        close(scf)


def test_high_level_commands_wait_for_notify_setpoint_stop_after_streaming(emu: CrazyflieEmulator) -> None:
    scf = connect(emu)
    cf = scf.cf
    try:
        cf.supervisor.send_arming_request(True)
        assert wait_for(lambda: emu.snapshot().armed)
        cf.high_level_commander.takeoff(1.0, 1.0)
        assert wait_for(lambda: emu.snapshot().z > 0.95)
        for _ in range(10):
            cf.commander.send_velocity_world_setpoint(0.5, 0.0, 0.0, 0.0)
            time.sleep(0.05)
        assert emu.snapshot().streaming and emu.snapshot().vx > 0.3
        cf.high_level_commander.land(0.0, 1.0)  # ignored: a streamed set-point has priority
        time.sleep(0.3)
        assert emu.snapshot().hl_kind == ""
        cf.commander.send_notify_setpoint_stop()
        cf.high_level_commander.land(0.0, 1.0)
        assert wait_for(lambda: not emu.snapshot().flying)
        assert emu.notify_stops == 1
    finally:
        close(scf)


def test_watchdog_stops_the_motors_two_seconds_after_the_last_setpoint(emu: CrazyflieEmulator) -> None:
    scf = connect(emu)
    cf = scf.cf
    try:
        cf.supervisor.send_arming_request(True)
        assert wait_for(lambda: emu.snapshot().armed)
        cf.commander.send_hover_setpoint(0.0, 0.0, 0.0, 0.8)
        assert wait_for(lambda: emu.snapshot().z > 0.05)
        assert wait_for(lambda: not emu.snapshot().flying, timeout=5.0)
        snap = emu.snapshot()
        assert snap.locked and snap.z == 0.0
        got, _ = stream(scf, ["supervisor.info"])
        assert wait_for(lambda: bool(got))
        assert got[-1][1]["supervisor.info"] >> 6 & 1  # locked bit
    finally:
        close(scf)


def test_locked_supervisor_refuses_to_arm_and_takeoff_does_nothing(emu: CrazyflieEmulator) -> None:
    emu.set_locked(True)
    scf = connect(emu)
    cf = scf.cf
    try:
        cf.supervisor.send_arming_request(True)
        assert wait_for(lambda: any(p == 9 and ch == 1 for p, ch, _ in emu.received))
        time.sleep(0.2)
        cf.high_level_commander.takeoff(1.0, 1.0)
        time.sleep(0.5)
        snap = emu.snapshot()
        assert not snap.armed and not snap.flying and snap.z == 0.0
    finally:
        close(scf)


@pytest.mark.parametrize(
    ("volts", "level"), [(4.2, 90), (4.05, 90), (3.9, 50), (3.79, 20), (3.5, 10), (2.9, 0)]
)
def test_battery_level_follows_the_firmware_charge_curve(volts: float, level: int) -> None:
    assert battery_level(volts) == level


def test_battery_drains_in_flight_into_low_power(emu: CrazyflieEmulator) -> None:
    emu.drain = 2.0  # V/s: seconds to empty
    emu.set_battery(3.4)
    scf = connect(emu)
    cf = scf.cf
    try:
        got, _ = stream(scf, ["pm.vbat", "pm.state"])
        cf.supervisor.send_arming_request(True)
        assert wait_for(lambda: emu.snapshot().armed)
        cf.high_level_commander.takeoff(0.5, 1.0)
        assert wait_for(lambda: bool(got) and got[-1][1]["pm.state"] == 3)
        assert got[-1][1]["pm.vbat"] < 3.2
    finally:
        close(scf)


def test_silence_stops_every_packet_both_ways(emu: CrazyflieEmulator) -> None:
    scf = connect(emu)
    try:
        got, _ = stream(scf, ["pm.vbat"])
        assert wait_for(lambda: len(got) > 2)
        emu.set_silent(True)
        time.sleep(0.2)
        n, received = len(got), len(emu.received)
        time.sleep(0.5)
        assert len(got) == n and len(emu.received) == received
        emu.set_silent(False)
        assert wait_for(lambda: len(got) > n)
    finally:
        close(scf)


def test_cflib_closing_the_link_in_flight_stops_the_motors(emu: CrazyflieEmulator) -> None:
    """cflib's close_link sends a zero-thrust legacy set-point: why the adapter closes links without it."""
    scf = connect(emu)
    scf.cf.supervisor.send_arming_request(True)
    assert wait_for(lambda: emu.snapshot().armed)
    scf.cf.high_level_commander.takeoff(0.5, 1.0)
    assert wait_for(lambda: emu.snapshot().z > 0.4)
    close(scf)
    assert wait_for(lambda: not emu.snapshot().flying)
    assert emu.snapshot().z == 0.0
