"""`TelloAdapter` through the real djitellopy against the Tello SDK emulator (docs/design.md §7, §12).

djitellopy binds UDP 8889/8890 on all addresses once per process, so the emulator cannot share a
network namespace with it (see tests/harness/netns.py). The emulator runs in this process on a
socket made in namespace ``a`` (192.168.10.1, the real Tello's address); the adapter runs in a
driver process in namespace ``b`` that takes JSON requests on stdin ("make an adapter", "call
takeoff(1.5)", "give me state()") and answers one JSON line each. The test compares what the
adapter reports with the emulator's ground truth and injects faults into the emulator directly.
One namespace pair and one driver serve the whole module; each test gets a fresh emulator and a
fresh adapter.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.vehicles import load_adapter
from antalate_lcm.vehicles.tello import TelloAdapter
from tests.emulators.tello_emulator import TelloEmulator
from tests.harness.netns import NetnsPair, netns_pair_unavailable

HOME = (32.7767, 35.0231)
SECOND_TELLO = "192.168.10.3"

#: Adapter params for quick tests: short timeouts so a failure costs seconds, not minutes.
FAST: dict[str, Any] = {
    "home_lat": HOME[0],
    "home_lon": HOME[1],
    "command_timeout": 2,
    "takeoff_timeout": 10,
    "retry_count": 1,
    "keepalive_s": 0.5,
    "link_loss_timeout": 1.0,
}
#: Emulator settings to match: a brisk takeoff and landing.
EMU: dict[str, Any] = {"takeoff_time": 0.5, "land_speed": 2.0}


class Driver:
    """The test's end of the driver process in namespace b (tests/children/tello_driver.py)."""

    def __init__(self, proc: subprocess.Popen[str], log_path: Path) -> None:
        self.proc = proc
        self.log_path = log_path

    def request(self, **req: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"driver died: {self.log_path.read_text()}")
        reply: dict[str, Any] = json.loads(line)
        return reply

    def new(self, name: str = "main", **params: Any) -> None:
        reply = self.request(op="new", name=name, params={**FAST, **params})
        assert reply["ok"], reply

    def call(self, method: str, *args: Any, name: str = "main") -> Any:
        reply = self.request(op="call", name=name, method=method, args=list(args))
        assert reply["ok"], f"{method}{args}: {reply}"
        return reply["result"]

    def fails(self, method: str, *args: Any, name: str = "main") -> dict[str, Any]:
        reply = self.request(op="call", name=name, method=method, args=list(args))
        assert not reply["ok"], f"{method}{args} should have failed"
        return reply

    def state(self, name: str = "main") -> dict[str, Any]:
        reply = self.request(op="state", name=name)
        assert reply["ok"], reply
        state: dict[str, Any] = reply["result"]
        return state

    def extra(self, name: str = "main") -> dict[str, Any]:
        extra: dict[str, Any] = self.request(op="extra", name=name)["result"]
        return extra

    def wait(
        self, pred: Callable[[dict[str, Any]], bool], timeout: float, name: str = "main"
    ) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            s = self.state(name)
            if pred(s):
                return s
            assert time.monotonic() < deadline, f"state never matched; last {s}"
            time.sleep(0.05)

    def fly(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: str, seconds: float) -> None:
        """Stream a set-point at 10 Hz for `seconds` (what the HLC does with a behavior's commands)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.call("set_velocity", vx, vy, vz, yaw_rate, frame)
            time.sleep(0.1)
        self.call("set_velocity", 0.0, 0.0, 0.0, 0.0, frame)


def ne_of(state: dict[str, Any]) -> tuple[float, float]:
    return FlatFrame(*HOME).to_ne(state["lat"], state["lon"])


def truth_ne(snap: Any, home_heading: float) -> tuple[float, float]:
    """The emulator's power-on frame (x along yaw 0, y to its right) as north/east."""
    psi = math.radians(home_heading)
    return snap.x * math.cos(psi) - snap.y * math.sin(psi), snap.x * math.sin(psi) + snap.y * math.cos(psi)


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


# ------------------------------------------------------------------------------ without a network


def test_registered_and_constructed_without_io() -> None:
    assert load_adapter("tello") is TelloAdapter
    ap = TelloAdapter({"host": "10.0.0.5"})
    s = ap.state()
    assert not s.connected and math.isinf(s.link_age)
    ap.close()  # idempotent, nothing opened


@pytest.mark.parametrize(
    ("params", "needle"),
    [
        ({"hots": "192.168.10.1"}, "hots"),
        ({"host": "tello.local"}, "host"),
        ({"max_speed": 0}, "max_speed"),
        ({"keepalive_s": 15}, "keepalive_s"),
        ({"vgx_sign": 2}, "vgx_sign"),
        ({"vgy_sign": True}, "vgy_sign"),
        ({"retry_count": 1.5}, "retry_count"),
        ({"command_timeout": "7"}, "command_timeout"),
        ({"takeoff_altitude_mode": "jump"}, "takeoff_altitude_mode"),
        ({"velocity_frame": "ned"}, "velocity_frame"),
        ({"altitude_source": "baro"}, "altitude_source"),
        ({"home_lat": 123.0}, "home_lat"),
        ({"rtl_speed": float("nan")}, "rtl_speed"),
        ({"djitellopy_log_level": "LOUD"}, "djitellopy_log_level"),
    ],
)
def test_params_are_validated(params: dict[str, Any], needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        TelloAdapter(params)


def test_rc_scale() -> None:
    """rc 100 = max_speed; horizontal clamped together (direction kept), the rest per channel."""
    ap = TelloAdapter({"max_speed": 2.0, "max_vertical_speed": 0.5, "max_yaw_rate": 90.0})
    assert ap._rc(1.0, -0.5, 0.25, 45.0) == (-25, 50, 50, 50)
    assert ap._rc(8.0, 4.0, -3.0, -500.0) == (50, 100, -100, -100)  # 4:2 keeps its 2:1 direction


def test_commands_need_a_connection() -> None:
    ap = TelloAdapter({})
    for call in (ap.arm, ap.land, ap.rtl, lambda: ap.takeoff(1.0)):
        with pytest.raises(Exception, match="not connected"):
            call()


# ------------------------------------------------------------------------------ against the emulator


@pytest.fixture(scope="module")
def net() -> Iterator[NetnsPair]:
    reason = netns_pair_unavailable()
    if reason:
        pytest.skip(reason)
    with NetnsPair(extra_addrs_a=[SECOND_TELLO]) as pair:
        yield pair


@pytest.fixture(scope="module")
def driver(net: NetnsPair, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Driver]:
    """The adapter's process; its log (stderr) goes to a file, shown when a test fails."""
    log_path = tmp_path_factory.mktemp("tello") / "driver.log"
    with open(log_path, "w") as log:
        proc = net.popen(
            "b",
            [sys.executable, "-m", "tests.children.tello_driver"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
        )
        yield Driver(proc, log_path)


@pytest.fixture
def emulator(net: NetnsPair, driver: Driver) -> Iterator[Callable[..., TelloEmulator]]:
    """A factory of emulators in namespace a (default 192.168.10.1); all stopped after the test."""
    made: list[TelloEmulator] = []

    def make(host: str = "192.168.10.1", **kw: Any) -> TelloEmulator:
        emu = TelloEmulator(sock=net.udp_socket("a", (host, 8889)), **{**EMU, **kw}).start()
        made.append(emu)
        return emu

    yield make
    for name in ("main", "second"):
        driver.request(op="call", name=name, method="close", args=[])
    for emu in made:
        emu.stop()


@pytest.mark.netns
def test_connect_reports_the_tello_on_the_ground(
    driver: Driver, emulator: Callable[..., TelloEmulator], net: NetnsPair
) -> None:
    emu = emulator()
    driver.new(home_heading=30.0)
    driver.call("connect")
    s = driver.state()
    assert s["connected"] and s["link_age"] < 0.5
    assert s["battery"] == 100 and s["mode"] == "GROUND" and not s["in_air"] and not s["armed"]
    assert s["autonomous"] and s["flight_mode"] == "GUIDED"
    assert (s["lat"], s["lon"]) == pytest.approx(HOME, abs=1e-9)
    assert s["heading"] == pytest.approx(30.0)
    snap = emu.snapshot()
    assert snap.sdk_mode and snap.client == (net.addr_b, 8889)
    assert driver.call("arm") is True  # no arming on a Tello: a check that it answers
    driver.call("disarm")  # a no-op on the ground
    assert not emu.snapshot().flying
    driver.call("connect")  # idempotent


@pytest.mark.netns
@pytest.mark.parametrize("mode", ["rc", "up"])
def test_takeoff_climbs_to_the_target_altitude(
    driver: Driver, emulator: Callable[..., TelloEmulator], mode: str
) -> None:
    emu = emulator()
    driver.new(takeoff_altitude_mode=mode)
    driver.call("connect")
    reply = driver.request(op="call", name="main", method="takeoff", args=[1.5])
    assert reply["ok"], reply
    if mode == "rc":
        assert reply["elapsed"] < 1.5  # returns after the Tello's own takeoff; the climb goes on
        s = driver.wait(lambda s: s["mode"] == "GUIDED", timeout=5)
    else:
        s = driver.state()  # "up" returns only at the altitude
        assert s["mode"] == "GUIDED"
    assert emu.snapshot().z == pytest.approx(1.5, abs=0.12)
    s = driver.wait(lambda s: abs(s["alt"] - emu.snapshot().z) < 0.1, timeout=1)
    assert s["in_air"] and s["armed"]
    texts = emu.command_texts()
    assert "takeoff" in texts
    assert any(t.startswith("up ") for t in texts) == (mode == "up")
    assert driver.extra()["dead_reckoning_problem"] == ""  # vgz (dm/s) agreed with the climb
    driver.fails("takeoff", 2.0)  # already flying
    driver.call("land")
    assert not emu.snapshot().flying
    s = driver.wait(lambda s: not s["in_air"], timeout=2)
    assert s["mode"] == "GROUND"


@pytest.mark.netns
def test_velocity_ned_and_body_and_dead_reckoning(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    heading0 = 90.0  # the Tello faced east at power-on
    emu = emulator()
    driver.new(home_heading=heading0)
    driver.call("connect")
    driver.call("takeoff", 0.8)  # the takeoff height: no climb needed
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=3)

    driver.fly(0.6, 0.0, 0.0, 0.0, "NED", 1.5)  # north
    time.sleep(0.6)
    north, east = truth_ne(emu.snapshot(), heading0)
    assert north > 0.7 and abs(east) < 0.1, (north, east)
    s = driver.state()
    assert ne_of(s) == pytest.approx((north, east), abs=0.2)

    driver.fly(0.0, 0.0, 0.0, 60.0, "BODY", 1.5)  # turn right by ~90 deg: now facing south
    time.sleep(0.3)
    snap = emu.snapshot()
    s = driver.state()
    assert angle_diff(s["heading"], heading0 + snap.yaw) < 2.0
    assert angle_diff(s["heading"], 180.0) < 15.0

    before = truth_ne(emu.snapshot(), heading0)
    driver.fly(0.6, 0.0, -0.3, 0.0, "BODY", 1.5)  # forward = south, and up
    time.sleep(0.6)
    snap = emu.snapshot()
    after = truth_ne(snap, heading0)
    assert after[0] - before[0] < -0.7 and abs(after[1] - before[1]) < 0.15, (before, after)
    assert snap.z > 1.1
    s = driver.state()
    assert ne_of(s) == pytest.approx(after, abs=0.3)
    assert s["alt"] == pytest.approx(snap.z, abs=0.1)
    assert abs(snap.vx) + abs(snap.vy) < 0.05  # the zero set-point stopped it
    driver.call("land")


@pytest.mark.netns
def test_keepalive_prevents_the_auto_landing(driver: Driver, emulator: Callable[..., TelloEmulator]) -> None:
    emu = emulator(auto_land_timeout=0.8)
    driver.new(keepalive_s=0.3)
    driver.call("connect")
    driver.call("takeoff", 0.8)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=2)  # (a packet from mid-takeoff may ask a trim)
    n_sent = len(emu.commands)
    time.sleep(2.0)  # idle hover, 2.5 x the emulator's auto-land timeout
    assert emu.snapshot().flying
    rcs = [c.text for c in emu.commands[n_sent:]]
    assert len(rcs) >= 4 and set(rcs) == {"rc 0 0 0 0"}
    driver.call("close")  # no more keepalives: the Tello's own failsafe lands it
    assert emu.wait_until(lambda s: not s.flying, timeout=3)


@pytest.mark.netns
def test_rtl_flies_back_and_lands(driver: Driver, emulator: Callable[..., TelloEmulator]) -> None:
    emu = emulator()
    driver.new(rtl_speed=0.8, rtl_tolerance=0.2, home_heading=200.0)
    driver.call("connect")
    driver.call("takeoff", 1.0)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=3)
    driver.fly(0.6, -0.4, 0.0, 20.0, "NED", 2.0)
    time.sleep(0.4)
    away = truth_ne(emu.snapshot(), 200.0)
    assert math.hypot(*away) > 1.0
    reply = driver.request(op="call", name="main", method="rtl", args=[])
    # rtl() returns once the Tello is seen closing in (half a metre), not at the end of the leg.
    assert reply["ok"] and reply["elapsed"] < 3.0, reply
    modes = [driver.state()["mode"]]
    s = driver.state()
    assert s["mode"] == "RTL" and s["flight_mode"] == "RTL"
    deadline = time.monotonic() + 12
    while modes[-1] != "GROUND" and time.monotonic() < deadline:
        time.sleep(0.05)
        s = driver.state()
        if s["mode"] != modes[-1]:
            modes.append(s["mode"])
    assert modes == ["RTL", "LAND", "GROUND"], modes
    snap = emu.snapshot()
    assert not snap.flying
    assert math.hypot(*truth_ne(snap, 200.0)) < 0.45
    assert driver.extra()["takeoff_point"] == [0.0, 0.0]
    driver.call("rtl")  # on the ground: nothing to do


@pytest.mark.netns
def test_link_loss_grows_link_age_and_stops_commanding(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    emu = emulator(auto_land_timeout=5.0)
    driver.new(keepalive_s=0.3, link_loss_timeout=0.5, link_back_hover=1.0)
    driver.call("connect")
    emu.stop_state()
    time.sleep(0.8)
    s = driver.state()
    assert s["connected"] and s["link_age"] > 0.7
    assert "link lost" in driver.fails("takeoff", 1.0)["error"]
    emu.resume_state()
    s = driver.wait(lambda s: s["link_age"] < 0.3, timeout=2)
    driver.call("takeoff", 0.8)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=2)
    n_sent = len(emu.commands)
    emu.stop_state()  # in flight: one hover, then silence (the Tello's own failsafe would land it)
    stopped = time.monotonic()
    time.sleep(1.2)
    assert driver.state()["link_age"] > 1.0
    sent = emu.commands[n_sent:]
    assert {c.text for c in sent} == {"rc 0 0 0 0"}
    assert not [c for c in sent if c.t > stopped + 0.5 + 0.15], "commands after link_loss_timeout"
    assert emu.snapshot().flying
    emu.resume_state()  # back before the failsafe fired: it hovers, waiting link_back_hover for a command
    s = driver.wait(lambda s: s["link_age"] < 0.3, timeout=2)
    assert s["mode"] == "GUIDED" and s["in_air"]
    # Nobody commands it (an HLC that stays in LLC_DOWN): the adapter ends the flight itself.
    s = driver.wait(lambda s: s["mode"] == "LAND", timeout=3)
    assert "nobody commanded" in s["failsafe"] and s["flight_mode"] == "LANDING"
    assert emu.wait_until(lambda s: not s.flying, timeout=3)
    assert "land" in emu.command_texts()[n_sent:]
    driver.wait(lambda s: s["mode"] == "GROUND" and not s["in_air"], timeout=2)


@pytest.mark.netns
def test_battery_reported_and_arm_refused_when_low(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    emu = emulator(battery=8.0)
    driver.new(min_battery=10.0)
    driver.call("connect")
    assert driver.state()["battery"] == 8
    assert driver.call("arm") is False
    emu.set_battery(55)
    driver.wait(lambda s: s["battery"] == 55, timeout=1)
    assert driver.call("arm") is True


@pytest.mark.netns
def test_refused_takeoff_raises_and_stays_on_the_ground(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    emu = emulator()
    emu.refuse_takeoff = True
    driver.new()
    driver.call("connect")
    err = driver.fails("takeoff", 1.0)
    assert err["type"] == "AutopilotError" and "takeoff" in err["error"]
    assert driver.state()["mode"] == "GROUND"


@pytest.mark.netns
def test_dead_host_is_a_clear_error(driver: Driver, emulator: Callable[..., TelloEmulator]) -> None:
    driver.new(host="192.168.10.77", command_timeout=1)
    err = driver.fails("connect")
    assert err["type"] == "AutopilotError"
    assert "no answer from the Tello at 192.168.10.77" in err["error"] and err["elapsed"] < 2.5
    assert driver.state()["connected"] is False
    emulator()  # djitellopy's shared receiver threads survived: a live Tello still connects
    driver.new()
    driver.call("connect")


@pytest.mark.netns
def test_two_tellos_in_one_process(driver: Driver, emulator: Callable[..., TelloEmulator]) -> None:
    first, second = emulator(), emulator(SECOND_TELLO, battery=70.0)
    driver.new()
    driver.new("second", host=SECOND_TELLO)
    driver.call("connect")
    driver.call("connect", name="second")
    assert driver.state()["battery"] == 100 and driver.state("second")["battery"] == 70
    driver.call("takeoff", 0.8, name="second")
    assert second.snapshot().flying and not first.snapshot().flying
    driver.new("third", host=SECOND_TELLO)
    assert "already flies" in driver.fails("connect", name="third")["error"]
    driver.call("land", name="second")
    driver.request(op="call", name="third", method="close", args=[])


@pytest.mark.netns
def test_port_in_use_by_another_process(net: NetnsPair, driver: Driver) -> None:
    """The driver process holds 8889 in namespace b: a second process there cannot fly a Tello."""
    done = net.run("b", [sys.executable, "-m", "tests.children.tello_connect"], timeout=30)
    assert done.stdout.startswith("AutopilotError") and "8889" in done.stdout, done.stdout + done.stderr


# ------------------------------------------------------------------------------ field faults (issue 12)


def rc_commands(emu: TelloEmulator, since: float, until: float) -> list[str]:
    return [c.text for c in emu.commands if c.text.startswith("rc ") and since <= c.t < until]


@pytest.mark.netns
def test_lost_ok_to_takeoff_is_settled_by_the_state_and_kept_alive(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    """The Tello took off but its "ok" was lost: takeoff() returns once the state shows it hovering.

    djitellopy waited out its 20 s timeout (and then sent a second ``takeoff``) while nothing kept the
    Tello from landing itself. Here the emulator lands itself 0.6 s after a command ends, shorter than
    the settling second, so only the keepalives sent during the wait hold it up.
    """
    emu = emulator(takeoff_time=1.0, auto_land_timeout=0.6)
    emu.lose_reply("takeoff")
    driver.new(takeoff_timeout=20, keepalive_s=0.2)
    driver.call("connect")
    reply = driver.request(op="call", name="main", method="takeoff", args=[0.8])
    assert reply["ok"], reply
    assert reply["elapsed"] < 5.0, reply  # takeoff 1 s + a settled second, not 20 s
    assert emu.lost_replies == [("takeoff", "ok")]
    assert emu.command_texts().count("takeoff") == 1  # never sent twice
    s = driver.state()
    assert s["mode"] == "GUIDED" and s["in_air"]
    time.sleep(1.5)
    assert emu.snapshot().flying, "auto-landed: no keepalive while takeoff waited for its answer"
    driver.call("land")


@pytest.mark.netns
def test_lost_ok_to_land_is_settled_by_the_state(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    emu = emulator()
    driver.new(takeoff_timeout=20)
    driver.call("connect")
    driver.call("takeoff", 0.8)
    emu.lose_reply("land")
    reply = driver.request(op="call", name="main", method="land", args=[])
    assert reply["ok"], reply
    assert reply["elapsed"] < 3.0, reply  # 0.4 s of descent and half a second on the ground, not 20 s
    assert emu.lost_replies == [("land", "ok")] and not emu.snapshot().flying
    s = driver.state()
    assert s["mode"] == "GROUND" and not s["in_air"] and s["flight_mode"] == "GUIDED"


@pytest.mark.netns
@pytest.mark.parametrize(("method", "sent"), [("land", "land"), ("emergency", "emergency"), ("rtl", "land")])
def test_land_rtl_and_emergency_preempt_a_waiting_takeoff(
    driver: Driver, emulator: Callable[..., TelloEmulator], method: str, sent: str
) -> None:
    """A takeoff whose answer never comes is given up at once by a LAND, an RTL or an emergency."""
    emu = emulator(takeoff_time=3.0)
    driver.new(takeoff_timeout=20)
    driver.call("connect")
    emu.mute_replies = True  # takeoff's answer never comes; nor does land's
    driver.request(op="start", tag="takeoff", method="takeoff", args=[1.0])
    assert emu.wait_until(lambda s: s.flying and s.z > 0.3, timeout=5)
    reply = driver.request(op="call", name="main", method=method, args=[])
    assert reply["ok"], reply
    done = driver.request(op="result", tag="takeoff")["result"]
    assert not done["ok"] and "interrupted" in done["error"], done
    assert done["elapsed"] < 4.0, done  # given up at once, not after takeoff_timeout
    assert emu.wait_until(lambda s: not s.flying, timeout=5)
    driver.wait(lambda s: s["mode"] == "GROUND" and not s["in_air"], timeout=3)
    texts = emu.command_texts()
    assert texts.count("takeoff") == 1 and sent in texts


@pytest.mark.netns
def test_commands_are_spaced_so_the_tello_hears_each_one_and_emergency_waits_for_no_answer(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    """A Tello ignores a command 0.1 s after the last one or its answer (djitellopy TIME_BTW_COMMANDS).

    The HLC arms (``battery?``) and takes off back to back: the take-off used to go out on the heels
    of the answer and was never heard (the adapter then timed out). ``emergency`` is never answered:
    it returns at once, spaced too, and the Tello drops.
    """
    emu = emulator()
    driver.new()
    driver.call("connect")
    assert driver.call("arm") is True
    driver.call("takeoff", 0.8)
    assert emu.snapshot().flying
    assert driver.call("arm") is True
    replies = len(emu.replies)
    reply = driver.request(op="call", name="main", method="emergency", args=[])
    assert reply["ok"] and reply["elapsed"] < 0.5, reply
    assert emu.wait_until(lambda s: not s.flying and s.z == 0.0, timeout=1)
    assert emu.ignored == []
    heard = [c for c in emu.commands if not c.text.startswith("rc ")]
    assert [c.text for c in heard] == ["command", "battery?", "takeoff", "battery?", "emergency"]
    assert min(b.t - a.t for a, b in zip(heard, heard[1:], strict=False)) >= 0.1
    assert len(emu.replies) == replies  # nothing answered the emergency
    assert driver.wait(lambda s: s["mode"] == "GROUND" and not s["in_air"], timeout=2)


@pytest.mark.netns
def test_a_slow_takeoff_is_not_reported_as_a_failure(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    """Take-off's "ok" 4 s after it, twice this test's command_timeout (2 s) as DJITelloPy #31's
    > 7 s is to the default 7 s; the Tello hovers meanwhile.

    The state settles the take-off a second after the climb stops; the ``up`` to the altitude then
    waits for the late "ok" (sent before it, the Tello answered "error" -- still in its take-off -- and
    the adapter reported the climb refused; and the late "ok" would have passed for up's answer).
    """
    emu = emulator(takeoff_time=1.0, takeoff_settle=3.0)
    driver.new(takeoff_altitude_mode="up", takeoff_timeout=20)
    driver.call("connect")
    reply = driver.request(op="call", name="main", method="takeoff", args=[1.5])
    heard = [
        (round(c.t - emu.commands[0].t, 2), c.text) for c in emu.commands if not c.text.startswith("rc ")
    ]
    assert reply["ok"], (reply, heard, emu.replies)
    assert reply["elapsed"] >= 4.0, reply  # the climb went after the take-off's own "ok"
    assert [text for text, _ in emu.replies].count("error") == 0
    assert [text.split()[0] for _, text in heard] == ["command", "takeoff", "up"]  # one up, heard
    assert emu.snapshot().z == pytest.approx(1.5, abs=0.12)
    s = driver.state()
    assert s["mode"] == "GUIDED" and s["in_air"]
    driver.call("land")
    assert not emu.snapshot().flying


@pytest.mark.netns
def test_velocities_not_in_dm_per_s_are_found_and_rtl_lands_where_it_is(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    """The SDK leaves vgx/vgy/vgz's unit open; a Tello reporting cm/s is found by its take-off climb.

    Dead reckoning would put home ten times too far: the RTL is refused and the Tello lands here.
    """
    emu = emulator(velocity_scale=100.0, land_speed=0.5)
    driver.new()
    driver.call("connect")
    driver.call("takeoff", 0.8)
    problem = driver.extra()["dead_reckoning_problem"]
    ratio = re.search(r"\(x([0-9.]+)\)", problem)
    assert ratio and 5 < float(ratio.group(1)) < 20 and "dm/s" in problem, problem
    fail = driver.fails("rtl")
    assert "dead reckoning unreliable" in fail["error"], fail
    s = driver.wait(lambda s: s["mode"] == "LAND", timeout=1)  # what the HLC shows while it lands
    assert s["flight_mode"] == "LANDING" and "RTL failed: dead reckoning unreliable" in s["failsafe"], s
    assert emu.wait_until(lambda s: not s.flying, timeout=5)
    driver.wait(lambda s: s["mode"] == "GROUND" and not s["in_air"], timeout=3)


@pytest.mark.netns
@pytest.mark.parametrize("control_hz", [20.0, 10.0])
def test_rc_goes_out_at_the_configured_rate(
    driver: Driver, emulator: Callable[..., TelloEmulator], control_hz: float
) -> None:
    """Set-points arrive at 10 Hz; rc leaves at control_hz (it was control_hz + 10: each set-point sent twice)."""
    emu = emulator()
    driver.new(control_hz=control_hz)
    driver.call("connect")
    driver.call("takeoff", 0.8)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=3)
    start = time.monotonic()
    driver.fly(0.3, 0.0, 0.0, 10.0, "BODY", 3.0)
    end = time.monotonic()
    window = (start + 0.5, end - 0.5)  # the steady part
    moving = [t for t in rc_commands(emu, *window) if t != "rc 0 0 0 0"]
    rate = len(moving) / (window[1] - window[0])
    assert 0.6 * control_hz <= rate <= 1.05 * control_hz, f"{rate:.1f} rc/s for control_hz {control_hz:g}"
    driver.call("land")


@pytest.mark.netns
def test_rtl_getting_farther_raises_and_lands_here(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    """Wrong sign conventions: the RTL flies away from home. rtl() says so (hlc_error_t) and it lands."""
    emu = emulator()
    driver.new(vgx_sign=-1, vgy_sign=-1, rtl_speed=0.8)  # the emulator's true signs are +1
    driver.call("connect")
    driver.call("takeoff", 0.8)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=3)
    driver.fly(0.6, 0.0, 0.0, 0.0, "BODY", 1.5)
    err = driver.fails("rtl")
    assert err["type"] == "AutopilotError" and err["error"].startswith("getting farther"), err
    assert "vgx_sign" in err["error"] and err["elapsed"] < 5.0
    s = driver.state()
    assert s["mode"] in ("LAND", "GROUND")
    if s["mode"] == "LAND":
        assert s["flight_mode"] == "LANDING" and "getting farther" in s["failsafe"]
    assert emu.wait_until(lambda s: not s.flying, timeout=5)
    driver.wait(lambda s: s["mode"] == "GROUND", timeout=3)


@pytest.mark.netns
def test_six_second_link_loss_in_flight_recovers_without_a_restart(
    driver: Driver, emulator: Callable[..., TelloEmulator]
) -> None:
    """Wi-Fi down both ways for 6 s; the Tello lands itself and comes back out of SDK mode.

    The adapter stops commanding it, probes with ``command`` once it must have landed (``autoland_s``
    after our last command), and reports a fresh link and a Tello on the ground: no restart needed.
    """
    emu = emulator(auto_land_timeout=2.0)
    emu.forget_sdk_on_silence = True
    driver.new(link_loss_timeout=0.5, autoland_s=2.0, keepalive_s=0.5)
    driver.call("connect")
    driver.call("takeoff", 0.8)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=3)
    emu.silence(6.0)
    s = driver.wait(lambda s: s["link_age"] > 1.0, timeout=3)
    assert s["connected"] and "link lost" in driver.fails("rtl")["error"]
    assert emu.wait_until(lambda s: not s.flying, timeout=6), "the Tello's own failsafe did not land it"
    assert emu.silent()  # it landed during the loss
    s = driver.wait(lambda s: s["link_age"] < 0.5, timeout=10)
    assert s["mode"] == "GROUND" and not s["in_air"]
    assert emu.snapshot().sdk_mode
    assert "command" in [c.text for c in emu.commands if c.t > emu.commands[0].t + 1.0]  # re-entered SDK mode
    assert driver.call("arm") is True  # and it flies again
    driver.call("takeoff", 0.8)
    driver.wait(lambda s: s["mode"] == "GUIDED", timeout=3)
    driver.call("land")
