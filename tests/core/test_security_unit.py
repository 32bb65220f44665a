"""The security mechanisms, pure: MAC and key rotation, the window, the replay guard and its file,
the authenticator's counters and log, input validation, the keygen."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import pytest

from antalate_lcm.msgs import direction_cmd_t, mc_state_t, operator_cmd_t, payload_t, velocity_cmd_t
from antalate_lcm.wire import validation
from antalate_lcm.wire.security import (
    Authenticator,
    HighWaterStore,
    Reason,
    ReplayGuard,
    SecurityPolicy,
    check_window,
    generate_key,
    network_reachable,
    sign,
    verify,
)
from behaviors.dovrat_swarm.logic import parse_detection_payload

KEY, OLD = "current-key", "previous-key"
T0 = 1_800_000_000.0


def _cmd(utime: float = T0, agent: str = "operator", seq: int = 1, key: str = KEY) -> operator_cmd_t:
    msg = operator_cmd_t()
    msg.command = operator_cmd_t.TAKEOFF
    msg.header.utime, msg.header.agent, msg.header.seq = int(utime * 1e6), agent, seq
    if key:
        sign(msg, key)
    return msg


# ---------------------------------------------------------------------------------------------- MAC
def test_a_previous_key_verifies_during_a_rotation_and_only_while_listed() -> None:
    old = _cmd(key=OLD)
    assert verify(old, KEY, 5.0, now=T0, previous_keys=[OLD]) is None
    assert verify(old, KEY, 5.0, now=T0) == "bad MAC (forged, or signed with another key)"
    assert verify(_cmd(key=""), KEY, 5.0, now=T0) == "unsigned message while a swarm key is configured"


def test_a_changed_field_breaks_the_mac() -> None:
    msg = _cmd()
    msg.altitude = 120.0
    assert verify(msg, KEY, 5.0, now=T0) is not None


def test_window_says_which_way_the_clock_is_off() -> None:
    ahead = check_window(_cmd(utime=T0 + 30), 5.0, T0)
    behind = check_window(_cmd(utime=T0 - 30), 5.0, T0)
    assert ahead is not None and "30.0 s ahead" in ahead.text and ahead.reason is Reason.STALE
    assert behind is not None and "age +30.0 s" in behind.text
    assert check_window(_cmd(utime=T0 - 4.9), 5.0, T0) is None


def test_keygen_makes_long_distinct_keys() -> None:
    keys = {generate_key() for _ in range(20)}
    assert len(keys) == 20 and all(len(k) >= 43 for k in keys)


def test_network_reachable_buses() -> None:
    assert network_reachable("udpm://239.255.76.67:7667?ttl=0")  # ttl limits sending only
    assert not network_reachable("memq://") and not network_reachable("file:///tmp/x.lcm?mode=r")


# ---------------------------------------------------------------------------------------------- replay
def test_replay_guard_wants_strictly_increasing_utime_per_sender_and_type() -> None:
    guard = ReplayGuard()
    first, later = _cmd(T0), _cmd(T0 + 1)
    assert guard.check(first, "operator", "operator_cmd_t") is None
    assert guard.check(later, "operator", "operator_cmd_t") is None
    replay = _cmd(T0)
    problem = guard.check(replay, "operator", "operator_cmd_t")
    assert problem is not None and problem.reason is Reason.REPLAYED
    # another sender, another type: their own counters
    assert guard.check(_cmd(T0), "console-2", "operator_cmd_t") is None
    assert guard.check(_cmd(T0), "operator", "direction_cmd_t") is None


def test_one_datagram_handed_to_two_subscriptions_is_not_a_replay() -> None:
    guard = ReplayGuard()
    msg = _cmd(T0)
    assert guard.check(msg, "operator", "operator_cmd_t") is None
    assert guard.check(msg, "operator", "operator_cmd_t") is None  # the same decoded object
    assert guard.check(_cmd(T0), "operator", "operator_cmd_t") is not None  # a copy is a replay


def test_a_resend_with_the_same_seq_and_a_fresh_utime_passes() -> None:
    guard = ReplayGuard()
    assert guard.check(_cmd(T0, seq=7), "operator", "operator_cmd_t") is None
    assert guard.check(_cmd(T0 + 0.5, seq=7), "operator", "operator_cmd_t") is None


def test_the_replay_memory_survives_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "state" / "alpha.mc.replay.json"
    guard = ReplayGuard(HighWaterStore(path), persisted={"operator_cmd_t"})
    assert guard.check(_cmd(T0), "operator", "operator_cmd_t") is None
    assert guard.check(_cmd(T0), "alpha", "mc_state_t") is None  # not persisted: superseded at 5 Hz
    assert json.loads(path.read_text()) == {"operator_cmd_t/operator": int(T0 * 1e6)}
    assert not list(path.parent.glob("*.tmp"))  # written through a temporary file, renamed
    restarted = ReplayGuard(HighWaterStore(path), persisted={"operator_cmd_t"})
    problem = restarted.check(_cmd(T0), "operator", "operator_cmd_t")
    assert problem is not None and problem.reason is Reason.REPLAYED
    assert restarted.check(_cmd(T0 + 0.1), "operator", "operator_cmd_t") is None


def test_an_unreadable_replay_memory_is_reported_and_replaced(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "m.json"
    path.write_text("{half a fi")
    store = HighWaterStore(path)
    assert store.load() == {}
    assert "unreadable" in caplog.text
    guard = ReplayGuard(store, persisted={"operator_cmd_t"})
    assert guard.check(_cmd(T0), "operator", "operator_cmd_t") is None
    assert json.loads(path.read_text()) == {"operator_cmd_t/operator": int(T0 * 1e6)}


# ---------------------------------------------------------------------------------------------- authenticator
def test_authenticator_counts_each_reason_and_logs_one_line_per_reason(
    caplog: pytest.LogCaptureFixture,
) -> None:
    logger = logging.getLogger("test.auth")
    auth = Authenticator(SecurityPolicy(KEY, (OLD,), 5.0), logger, wallclock=lambda: T0)
    caplog.set_level(logging.WARNING, logger="test.auth")
    assert auth.check(_cmd(T0), "alpha/OPERATOR_CMD") is None
    for i in range(50):
        assert auth.check(_cmd(T0 + i * 0.01, key=""), "alpha/OPERATOR_CMD") is not None
    assert auth.check(_cmd(T0 + 1, key="wrong"), "alpha/OPERATOR_CMD") is not None
    assert auth.check(_cmd(T0 - 60), "alpha/OPERATOR_CMD") is not None
    assert auth.check(_cmd(T0), "alpha/OPERATOR_CMD") is not None  # a copy of the first
    state = mc_state_t()
    state.header.utime, state.header.agent = int(T0 * 1e6), "beta"
    sign(state, KEY)
    problem = auth.check(state, "alpha/MC_STATE", expected_sender="alpha")
    assert problem is not None and problem.reason is Reason.WRONG_SENDER
    assert auth.rejected == {
        Reason.UNSIGNED: 50,
        Reason.FORGED: 1,
        Reason.STALE: 1,
        Reason.REPLAYED: 1,
        Reason.WRONG_SENDER: 1,
    }
    assert auth.accepted == 1
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 5, lines  # one per reason and channel, not fifty for the unsigned flood
    assert any("age +60.0 s" in line for line in lines)


# ---------------------------------------------------------------------------------------------- validation
def _direction(azimuth: float, speed: float) -> direction_cmd_t:
    msg = direction_cmd_t()
    msg.active, msg.azimuth, msg.speed = True, azimuth, speed
    return msg


def _payload(data: bytes, content_type: str = "application/json") -> payload_t:
    msg = payload_t()
    msg.content_type, msg.data, msg.size = content_type, data, len(data)
    return msg


@pytest.mark.parametrize(
    ("msg", "expected"),
    [
        (_direction(math.inf, 1.0), "azimuth is inf"),
        (_direction(math.nan, 1.0), "azimuth is nan"),
        (_direction(90.0, -1.0), "speed -1 is outside"),
        (_direction(1e30, 1.0), "azimuth 1e+30 is outside"),
        (_payload(b'{"detected": true, "count": Infinity}'), "not valid JSON: Infinity is not JSON"),
        (_payload(b'{"detected": true, "nearest_range": NaN}'), "NaN is not JSON"),
        (_payload(b'{"detected": true, "nearest_bearing": 1e999}'), "1e999 overflows"),
        (_payload(b"\xff\xfe"), "not valid JSON"),
    ],
)
def test_nonsense_is_rejected_with_a_reason(msg: object, expected: str) -> None:
    problem = validation.problem(msg)
    assert problem is not None and expected in problem


def test_operator_altitude_and_velocity_bounds() -> None:
    cmd = _cmd(key="")
    for bad in (math.inf, math.nan, -1.0, 1e6):
        cmd.altitude = bad
        assert validation.problem(cmd) is not None
    cmd.altitude = 0.0
    assert validation.problem(cmd) is None
    vel = velocity_cmd_t()
    vel.frame, vel.vx = velocity_cmd_t.NED, 3.2
    assert validation.problem(vel) is None
    vel.vy = math.nan
    assert "vy is nan" in (validation.problem(vel) or "")
    vel.vy, vel.frame = 0.0, 7
    assert "frame 7" in (validation.problem(vel) or "")


@pytest.mark.parametrize("field", ["vx", "vy", "vz", "yaw_rate"])
def test_every_velocity_field_is_checked_for_nan_inf_and_its_bounds(field: str) -> None:
    """The in-bounds case is told in one expression (`validation._velocity`): each field still
    refuses NaN, both infinities and one step past its bound, and accepts the bound itself."""
    bound = validation.MAX_YAW_RATE if field == "yaw_rate" else validation.MAX_VELOCITY
    vel = velocity_cmd_t()
    vel.frame = velocity_cmd_t.BODY
    for bad, expected in (
        (math.nan, f"{field} is nan"),
        (math.inf, f"{field} is inf"),
        (-math.inf, f"{field} is -inf"),
        (math.nextafter(bound, math.inf), f"{field} {bound:g} is outside"),
        (-math.nextafter(bound, math.inf), f"{field} {-bound:g} is outside"),
    ):
        setattr(vel, field, bad)
        assert expected in (validation.problem(vel) or ""), (field, bad)
    for good in (bound, -bound, 0.0, 1):
        setattr(vel, field, good)
        assert validation.problem(vel) is None, (field, good)
    setattr(vel, field, "50")  # not a number on the wire, but as `float` has it: as before
    assert validation.problem(vel) is None
    setattr(vel, field, "a lot")
    with pytest.raises(ValueError):
        validation.problem(vel)


def test_payload_size_must_match_and_other_content_types_pass() -> None:
    msg = _payload(b"\x00\x01binary", "application/octet-stream")
    assert validation.problem(msg) is None
    msg.size = 99
    assert "size 99" in (validation.problem(msg) or "")


@pytest.mark.parametrize(
    "body",
    [
        '{"detected": true, "count": Infinity}',
        '{"detected": true, "count": "3"}',
        '{"detected": true, "count": true}',
        '{"detected": true, "count": -2}',
        '{"detected": true, "count": 2.5}',
        '{"detected": true, "nearest_range": "far"}',
        '{"detected": true, "nearest_bearing": 1e999}',
    ],
)
def test_dovrat_payload_with_wrong_types_is_not_a_detection(body: str) -> None:
    assert parse_detection_payload(body.encode()) is None


def test_dovrat_payload_that_is_right_is_a_detection() -> None:
    d = parse_detection_payload(
        b'{"detected": true, "count": 2, "nearest_range": 12.5, "nearest_bearing": -3}'
    )
    assert d is not None and d.count == 2 and d.nearest_range == 12.5


def test_antalate_keygen_prints_a_fresh_key_each_time() -> None:
    import subprocess
    import sys

    run = [sys.executable, "-m", "antalate_lcm.cli", "keygen"]
    a, b = (subprocess.run(run, capture_output=True, text=True, timeout=30) for _ in range(2))
    assert a.returncode == 0 and b.returncode == 0, a.stderr
    assert a.stdout.strip() != b.stdout.strip() and len(a.stdout.strip()) >= 43


@pytest.mark.parametrize("agent", ["", "alpha", "ünïcode-ägent", "x" * 300])
def test_signed_bytes_equal_sign_then_encode(agent: str) -> None:
    """Node.publish splices the MAC into the unsigned encoding: it must be the very same bytes."""
    from antalate_lcm.msgs import telemetry_t
    from antalate_lcm.wire.security import signed_bytes

    for msg in (_cmd(agent=agent, key=""), telemetry_t()):
        msg.header.agent, msg.header.utime, msg.header.seq = agent, int(T0 * 1e6), 9
        spliced = signed_bytes(msg, KEY)
        sign(msg, KEY)
        assert spliced == msg.encode()
        decoded = type(msg).decode(spliced)
        assert verify(decoded, KEY, 5.0, now=T0) is None


def test_check_datagram_verifies_encoded_bytes_as_check_mac_does() -> None:
    """The console's path: the MAC checked on the datagram, without decoding it."""
    from antalate_lcm.msgs import mc_state_t
    from antalate_lcm.wire.security import Reason, check_datagram, signed_bytes

    msg = mc_state_t()
    msg.header.agent, msg.header.utime, msg.header.seq = "alpha", 1_800_000_000_000_000, 7
    msg.state, msg.last_command_seq = mc_state_t.TAKEOFF, 3
    data = signed_bytes(msg, "k")
    assert check_datagram(data, ["k"], 5.0, 1_800_000_001.0) is None
    assert check_datagram(data, ["old", "k"], 5.0, 1_800_000_001.0) is None  # a previous key
    forged = check_datagram(data, ["other"], 5.0, 1_800_000_001.0)
    assert forged is not None and forged.reason is Reason.FORGED
    tampered = bytearray(data)
    tampered[-5] ^= 1  # a byte of the body
    bad = check_datagram(bytes(tampered), ["k"], 5.0, 1_800_000_001.0)
    assert bad is not None and bad.reason is Reason.FORGED
    stale = check_datagram(data, ["k"], 5.0, 1_800_000_100.0)
    assert stale is not None and stale.reason is Reason.STALE
    unsigned = mc_state_t()
    unsigned.header.agent = "alpha"
    for junk in (unsigned.encode(), data[:12], b""):
        problem = check_datagram(junk, ["k"], 5.0, 1_800_000_001.0)
        assert problem is not None and problem.reason is Reason.UNSIGNED
