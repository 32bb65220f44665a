"""Velocity guard: state gating, non-finite rejection, clamping, staleness and the hover-once timer."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest

from antalate_lcm.agent.hlc.velocity_guard import (
    GuardDecision,
    Velocity,
    VelocityCommand,
    VelocityGuard,
    VelocityLimits,
    Verdict,
    check_velocity,
)
from antalate_lcm.vehicles.base import Frame
from antalate_lcm.wire.vocabulary import HlcState, McState

LIMITS = VelocityLimits(max_horizontal=5.0, max_vertical=2.0, max_yaw_rate=90.0, velocity_timeout=0.5)
OK = (HlcState.AIRBORNE, McState.MISSION)


def cmd(
    vx: float = 1.0,
    vy: float = 0.0,
    vz: float = 0.0,
    yaw: float = 0.0,
    frame: Frame | int = Frame.NED,
    at: float = 100.0,
) -> VelocityCommand:
    return VelocityCommand(vx, vy, vz, yaw, frame, at)


def check(
    command: VelocityCommand, now: float = 100.0, states: tuple[HlcState, McState | None] = OK
) -> GuardDecision:
    return check_velocity(command, now, states[0], states[1], LIMITS)


def test_within_limits_passes_unchanged() -> None:
    d = check(cmd(3.0, -2.0, 1.0, -45.0, Frame.BODY))
    assert d.verdict is Verdict.SEND and d.accepted and not d.clamped and d.reason == ""
    assert d.send == Velocity(3.0, -2.0, 1.0, -45.0, Frame.BODY)


WRONG_STATES = [(h, m) for h in HlcState for m in [*McState, None] if (h, m) != OK]


@pytest.mark.parametrize("states", WRONG_STATES, ids=lambda s: f"{s[0].name}-{getattr(s[1], 'name', None)}")
def test_only_airborne_in_mission(states: tuple[HlcState, McState | None]) -> None:
    d = check(cmd(), states=states)
    assert d.verdict is Verdict.REJECT and d.send is None
    assert "AIRBORNE" in d.reason and "MISSION" in d.reason


def test_plain_ints_from_the_wire() -> None:
    assert check_velocity(cmd(), 100.0, 4, 3, LIMITS).accepted
    d = check_velocity(cmd(), 100.0, 4, 42, LIMITS)
    assert not d.accepted and "42" in d.reason


@pytest.mark.parametrize("field", ["vx", "vy", "vz", "yaw"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_rejected(field: str, bad: float) -> None:
    fields: dict[str, Any] = {field: bad}
    d = check(cmd(**fields))
    assert d.verdict is Verdict.REJECT and d.send is None
    assert "non-finite" in d.reason and ("yaw_rate" if field == "yaw" else field) in d.reason


def test_unknown_frame_rejected() -> None:
    d = check(cmd(frame=7))
    assert d.verdict is Verdict.REJECT and "frame" in d.reason


def test_horizontal_norm_is_clamped_keeping_direction() -> None:
    d = check(cmd(6.0, 8.0))  # 10 m/s at atan2(8, 6)
    assert d.verdict is Verdict.SEND and d.clamped and d.send is not None
    assert math.hypot(d.send.vx, d.send.vy) == pytest.approx(5.0)
    assert d.send.vy / d.send.vx == pytest.approx(8.0 / 6.0)
    assert "horizontal" in d.reason


def test_diagonal_below_the_norm_is_not_clamped() -> None:
    d = check(cmd(3.5, 3.5))  # 4.95 m/s: each component fine and the norm too
    assert not d.clamped and d.send == Velocity(3.5, 3.5, 0.0, 0.0, Frame.NED)


@pytest.mark.parametrize("vz, expected", [(3.0, 2.0), (-7.0, -2.0), (1.5, 1.5)])
def test_vertical_clamped(vz: float, expected: float) -> None:
    d = check(cmd(vz=vz))
    assert d.send is not None and d.send.vz == expected
    assert d.clamped == (vz != expected)


@pytest.mark.parametrize("yaw, expected", [(200.0, 90.0), (-91.0, -90.0), (89.0, 89.0)])
def test_yaw_rate_clamped(yaw: float, expected: float) -> None:
    d = check(cmd(yaw=yaw))
    assert d.send is not None and d.send.yaw_rate == expected
    assert d.clamped == (yaw != expected)
    if d.clamped:
        assert "yaw" in d.reason


def test_stale_command_becomes_hover() -> None:
    assert check(cmd(at=100.0), now=100.5).verdict is Verdict.SEND  # exactly the timeout: still fresh
    d = check(cmd(4.0, at=100.0), now=100.51)
    assert d.verdict is Verdict.HOVER
    assert d.send == Velocity.hover() == Velocity(0.0, 0.0, 0.0, 0.0, Frame.BODY)
    assert "stale" in d.reason


def test_guard_hovers_once_after_commands_stop() -> None:
    guard = VelocityGuard(LIMITS)
    assert guard.on_command(cmd(at=10.0), 10.0, *OK).accepted
    assert guard.tick(10.4, *OK) is None
    d = guard.tick(10.6, *OK)
    assert d is not None and d.verdict is Verdict.HOVER and d.send == Velocity.hover()
    assert guard.tick(10.7, *OK) is None  # once
    assert guard.tick(20.0, *OK) is None
    assert guard.on_command(cmd(at=20.0), 20.0, *OK).accepted  # a new command re-arms the timer
    d = guard.tick(20.6, *OK)
    assert d is not None and d.verdict is Verdict.HOVER


def test_guard_stale_command_counts_as_the_hover() -> None:
    guard = VelocityGuard(LIMITS)
    guard.on_command(cmd(at=10.0), 10.0, *OK)
    assert guard.on_command(cmd(at=10.1), 11.0, *OK).verdict is Verdict.HOVER  # queued too long
    assert guard.tick(11.5, *OK) is None


def test_guard_silent_before_any_command_and_outside_mission() -> None:
    guard = VelocityGuard(LIMITS)
    assert guard.tick(100.0, *OK) is None
    guard.on_command(cmd(at=10.0), 10.0, *OK)
    # The HLC starts an RTL: the guard must not send hovers into the autopilot's manoeuvre.
    assert guard.tick(11.0, HlcState.RTL, McState.RTL) is None
    # Back to mission flight later (a new flight): no stale hover from the old command.
    assert guard.tick(50.0, *OK) is None


def test_guard_rejection_in_wrong_state_forgets_the_last_command() -> None:
    guard = VelocityGuard(LIMITS)
    guard.on_command(cmd(at=10.0), 10.0, *OK)
    assert not guard.on_command(cmd(at=10.2), 10.2, HlcState.LANDING, McState.LAND).accepted
    assert guard.tick(11.0, *OK) is None


def test_guard_non_finite_keeps_the_timer() -> None:
    guard = VelocityGuard(LIMITS)
    guard.on_command(cmd(at=10.0), 10.0, *OK)
    assert guard.on_command(cmd(vx=math.nan, at=10.3), 10.3, *OK).verdict is Verdict.REJECT
    d = guard.tick(10.6, *OK)  # the last good command still goes stale
    assert d is not None and d.verdict is Verdict.HOVER


def test_default_limits() -> None:
    assert VelocityLimits().velocity_timeout == 0.5
    assert VelocityGuard().limits == VelocityLimits()


@pytest.mark.parametrize("field", ["max_horizontal", "max_vertical", "max_yaw_rate", "velocity_timeout"])
@pytest.mark.parametrize("value", [-1.0, math.nan, math.inf])
def test_limits_validated(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        VelocityLimits(**{field: value})


ON_VELOCITY_CASES = list(
    itertools.product(
        [(1.0, 0.0), (3.0, -4.0), (6.0, 8.0), (-0.0, 0.0), (math.nan, 0.0), (0.0, math.inf)],
        [0.0, -0.0, 1.0, 2.0, -3.0, math.nan],
        [0.0, -0.0, 45.0, 90.0, -120.0, -math.inf],
        # A float or a bool from a hand-made message is looked up as the enum would (1.0 is NED).
        list[Any]([Frame.BODY, Frame.NED, 1, 1.0, True, 7]),
    )
)


@pytest.mark.parametrize(
    "limits", [LIMITS, VelocityLimits(max_horizontal=0.0, max_vertical=0.0, max_yaw_rate=0.0)]
)
@pytest.mark.parametrize("states", [OK, (HlcState.LANDING, McState.LAND)])
@pytest.mark.parametrize("link_age", [0.1, 3.0, math.nan])
def test_the_hlc_path_decides_what_on_command_does(
    limits: VelocityLimits, states: tuple[HlcState, McState], link_age: float
) -> None:
    """`VelocityGuard.passes` (the HLC's path: the values, nothing built when the command passes as
    it came) then, when it says None, `on_command`, decide exactly what `on_command` alone decides
    for a command received now, a zero's sign included (`repr`), and leave the guard in the same
    state; `passes` remembers nothing when it says None."""
    for (vx, vy), vz, yaw, frame in ON_VELOCITY_CASES:
        by_command, by_values = VelocityGuard(limits), VelocityGuard(limits)
        by_command.last_received = by_values.last_received = 1.0
        by_values._hovering = by_command._hovering = True
        expected = by_command.on_command(
            VelocityCommand(vx, vy, vz, yaw, frame, 100.0), 100.0, *states, link_age
        )
        known = by_values.passes(vx, vy, vz, yaw, frame, 100.0, *states, link_age)
        if known is None:
            assert (by_values.last_received, by_values._hovering) == (1.0, True)
            got = by_values.on_command(
                VelocityCommand(vx, vy, vz, yaw, frame, 100.0), 100.0, *states, link_age
            )
        else:
            assert expected.verdict is Verdict.SEND and not expected.clamped and expected.reason == ""
            got = GuardDecision(Verdict.SEND, Velocity(vx, vy, vz, yaw, known))
        assert repr(got) == repr(expected), (vx, vy, vz, yaw, frame)
        assert type(got.send.frame if got.send else None) is type(
            expected.send.frame if expected.send else None
        )
        assert (by_values.last_received, by_values._hovering) == (
            by_command.last_received,
            by_command._hovering,
        )
    fast = VelocityGuard(limits)
    assert (fast.passes(1.0, -0.0, 0.0, -0.0, 1, 5.0, *OK, 0.1) is Frame.NED) == (limits is LIMITS)


def test_a_zero_limit_clamps_to_the_same_signed_zero_as_before() -> None:
    """``max(-limit, min(limit, value))`` with a limit of 0: the clamp's own zero (-0.0), kept."""
    limits = VelocityLimits(max_vertical=0.0, max_yaw_rate=0.0)
    d = check_velocity(VelocityCommand(0.0, 0.0, 0.0, -0.0, Frame.NED, 1.0), 1.0, *OK, limits)
    assert d.send is not None and d.verdict is Verdict.SEND and not d.clamped
    assert math.copysign(1.0, d.send.vz) == math.copysign(1.0, max(-0.0, min(0.0, 0.0)))
    assert math.copysign(1.0, d.send.yaw_rate) == math.copysign(1.0, max(-0.0, min(0.0, -0.0)))
