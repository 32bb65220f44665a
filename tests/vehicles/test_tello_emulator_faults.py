"""The Tello emulator's field-fault knobs, with a bare SDK client on loopback (no djitellopy, no netns)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from tests.emulators.tello_emulator import TelloEmulator
from tests.vehicles.test_emulators import TelloClient


@pytest.fixture
def client() -> Iterator[TelloClient]:
    c = TelloClient()
    yield c
    c.close()


@pytest.fixture
def emu(client: TelloClient) -> Iterator[TelloEmulator]:
    with TelloEmulator("127.0.0.1", 0, state_port=client.state_port, takeoff_time=0.3, land_speed=2.0) as e:
        client.emulator = e.address
        assert client.ask("command") == "ok"
        yield e


def field(line: str, key: str) -> str:
    return dict(part.split(":", 1) for part in line.strip().strip(";").split(";") if ":" in part)[key]


def test_height_resolution_and_rounding() -> None:
    e = TelloEmulator("127.0.0.1", 0)
    e._z = 1.16  # noqa: SLF001 - set the truth directly: this is about the reporting only
    assert e.height_cm() == 120  # decimetres, rounded (as a real Tello reports h)
    e.height_rounding = "floor"
    assert e.height_cm() == 110
    e.height_resolution_cm = 1
    assert e.height_cm() == 116
    assert field(e.state_line(), "h") == "116" and field(e.state_line(), "tof") == "126"
    with pytest.raises(ValueError, match="height_rounding"):
        TelloEmulator("127.0.0.1", 0, height_rounding="ceil")


def test_lost_reply_is_executed_but_not_answered(emu: TelloEmulator, client: TelloClient) -> None:
    emu.lose_reply("takeoff")
    assert client.no_reply("takeoff", wait=1.0)
    assert emu.snapshot().flying and emu.snapshot().z == pytest.approx(0.8)
    assert emu.lost_replies == [("takeoff", "ok")]
    assert client.ask("sdk?") == "20"  # only that answer was lost
    emu.lose_reply("land")
    assert client.no_reply("land", wait=1.0)
    assert not emu.snapshot().flying


def test_silence_drops_both_ways_and_may_forget_sdk_mode(emu: TelloEmulator, client: TelloClient) -> None:
    assert client.state_packets(0.3)
    emu.forget_sdk_on_silence = True
    emu.silence(0.6)
    n = len(emu.commands)
    assert client.no_reply("battery?", wait=0.3)
    assert len(emu.commands) == n  # never heard: no command for the 15 s auto-landing either
    assert not client.state_packets(0.2)
    time.sleep(0.3)
    assert not emu.silent()
    assert not client.state_packets(0.3)  # back, but out of SDK mode
    assert client.ask("command") == "ok"
    assert client.state_packets(0.3)


def test_vertical_time_constant(emu: TelloEmulator, client: TelloClient) -> None:
    """A brisk Tello reaches the stick's climb rate sooner than a sluggish one."""
    assert client.ask("takeoff") == "ok"
    speeds = {}
    for tau in (0.15, 0.6):
        emu.vertical_tau = tau
        client.send("rc 0 0 50 0")
        time.sleep(0.3)
        speeds[tau] = emu.snapshot().vz
        emu.vertical_tau = 0.02  # stop at once for the next round
        client.send("rc 0 0 0 0")
        assert emu.wait_until(lambda s: abs(s.vz) < 0.01, timeout=3)
    assert speeds[0.15] > 0.4 > speeds[0.6] > 0.0, speeds


def test_a_command_too_soon_after_the_last_answer_is_ignored_but_rc_and_spaced_ones_are_heard(
    emu: TelloEmulator, client: TelloClient
) -> None:
    """djitellopy's TIME_BTW_COMMANDS (0.1 s): a closer command is neither carried out nor answered."""
    assert client.ask("battery?") == "100"
    client.spacing = 0.0  # a client that does not wait, as the adapter did before
    assert client.no_reply("takeoff", wait=0.3)  # sent at once after battery? (and its answer): ignored
    assert not emu.snapshot().flying
    assert [c.text for c in emu.ignored] == ["takeoff"]
    client.send("rc 0 0 0 0")  # rc is never spaced (TIME_BTW_RC_CONTROL_COMMANDS 0.001 s)
    time.sleep(0.05)
    assert emu.command_texts()[-1] == "rc 0 0 0 0" and len(emu.ignored) == 1
    client.spacing = 0.1
    assert client.ask("takeoff") == "ok"  # 0.1 s after the last one: heard
    assert emu.snapshot().flying


def test_emergency_is_never_answered_and_a_slow_takeoff_answers_after_its_settle(
    client: TelloClient,
) -> None:
    """takeoff's "ok" comes takeoff_time + takeoff_settle after it (DJITelloPy #31: > 7 s on real units)."""
    with TelloEmulator(
        "127.0.0.1", 0, state_port=client.state_port, takeoff_time=0.3, takeoff_settle=1.0
    ) as emu:
        client.emulator = emu.address
        assert client.ask("command") == "ok"
        t0 = time.monotonic()
        client.send("takeoff")
        assert emu.wait_until(lambda s: s.z >= 0.79, timeout=2)
        assert client.ask("up 50") == "error"  # the take-off is still the running manoeuvre
        client.cmd.settimeout(3.0)
        assert client.cmd.recvfrom(1024)[0] == b"ok"  # takeoff's, once it has settled
        assert time.monotonic() - t0 >= 1.25
        client.spacing = 0.0
        client.send("speed?")
        client.send("emergency")  # at once after a command: not heard either
        time.sleep(0.05)
        assert [c.text for c in emu.ignored] == ["emergency"] and emu.snapshot().flying
        assert client.cmd.recvfrom(1024)[0] != b""  # speed?'s answer
        client.spacing = 0.1
        client._quiet_since = time.monotonic()  # noqa: SLF001 - the answer above, read past the client
        assert client.no_reply("emergency", wait=0.5)  # spaced: heard, and never answered
        assert not emu.snapshot().flying and emu.snapshot().z == 0.0


def test_velocity_scale_sets_the_state_units() -> None:
    e = TelloEmulator("127.0.0.1", 0)
    e._vx, e._vz = 0.5, 0.3  # noqa: SLF001 - the truth, to read its report
    assert field(e.state_line(), "vgx") == "5" and field(e.state_line(), "vgz") == "-3"  # dm/s
    e.velocity_scale = 100.0
    assert field(e.state_line(), "vgx") == "50" and field(e.state_line(), "vgz") == "-30"  # cm/s
