"""direction_follow: the operator's direction as a NED velocity, through a BMA on memq://."""

from __future__ import annotations

import math

import pytest

from antalate_lcm.base.plugins import BEHAVIORS, load_plugin
from antalate_lcm.core.config import Config
from antalate_lcm.msgs import direction_cmd_t, velocity_cmd_t
from behaviors.direction_follow import Direction, DirectionFollow, follow_velocity
from tests.harness.bma import AGENT, Harness, harness, make_config
from tests.harness.polling import wait_for


def test_follow_velocity() -> None:
    east = Direction(True, 90.0, 0.5, received=10.0)
    assert follow_velocity(east, 10.5, timeout=3.0, max_speed=0.0) == pytest.approx((0.0, 0.5), abs=1e-12)
    assert follow_velocity(east, 13.5, timeout=3.0, max_speed=0.0) == (
        0.0,
        0.0,
    )  # stale: the operator is gone
    assert follow_velocity(None, 0.0, timeout=3.0, max_speed=0.0) == (0.0, 0.0)
    assert follow_velocity(Direction(False, 90.0, 0.5, 10.0), 10.0, timeout=3.0, max_speed=0.0) == (0.0, 0.0)
    fast_sw = Direction(True, 225.0, 4.0, received=0.0)
    vn, ve = follow_velocity(fast_sw, 0.0, timeout=3.0, max_speed=1.0)
    assert math.hypot(vn, ve) == pytest.approx(1.0) and vn < 0 and ve < 0
    for bad in (
        Direction(True, math.nan, 1.0, 0.0),
        Direction(True, 0.0, math.inf, 0.0),
        Direction(True, 0.0, -1.0, 0.0),
    ):
        assert follow_velocity(bad, 0.0, timeout=3.0, max_speed=0.0) == (0.0, 0.0)


def test_registered() -> None:
    assert load_plugin(BEHAVIORS, "direction_follow", object) is DirectionFollow


def _config(**params: float) -> Config:
    behavior = {"plugin": "direction_follow", "params": {"timeout": 0.5, **params}, "tick_hz": 20.0}
    return make_config([{"name": "steer", "behaviors": [behavior]}])


def _direction(
    h: Harness,
    azimuth: float,
    speed: float,
    *,
    active: bool = True,
    target: str = "",
    topic: str = "DIRECTION_CMD",
) -> None:
    msg = direction_cmd_t()
    msg.active, msg.azimuth, msg.speed, msg.target = active, azimuth, speed, target
    h.probe.publish(topic, msg)


def _becomes(cmds: list[velocity_cmd_t], vn: float, ve: float, timeout: float = 3.0) -> bool:
    return bool(
        wait_for(
            lambda: (
                cmds
                and cmds[-1].vx == pytest.approx(vn, abs=1e-6)
                and cmds[-1].vy == pytest.approx(ve, abs=1e-6)
            ),
            timeout,
        )
    )


def test_steers_in_mission_and_hovers_otherwise() -> None:
    with harness(_config()) as h:
        cmds = h.record("VELOCITY_CMD")
        h.bma("steer")
        _direction(h, 0.0, 0.8)  # set before MISSION: not flown yet
        h.mc_state("STANDBY")
        h.settle()
        assert cmds == []
        h.mc_state("MISSION")
        assert _becomes(cmds, 0.8, 0.0)
        cmd = cmds[-1]
        assert cmd.frame == velocity_cmd_t.NED and cmd.vz == 0.0 and cmd.yaw_rate == 0.0
        assert cmd.header.agent == AGENT
        assert _becomes(cmds, 0.0, 0.0, timeout=2.0)  # no repeat within timeout: hover
        _direction(h, 90.0, 0.5, topic="SWARM_DIRECTION_CMD")
        assert _becomes(cmds, 0.0, 0.5)
        _direction(h, 180.0, 0.5, target="someone-else")  # not for us: ignored
        h.settle()
        assert cmds[-1].vy == pytest.approx(0.5)
        _direction(h, 90.0, 0.5, active=False)
        assert _becomes(cmds, 0.0, 0.0)
        _direction(h, 270.0, 0.4)
        assert _becomes(cmds, 0.0, -0.4)
        h.mc_state("RTL")  # deactivated: one zero, then silence
        assert _becomes(cmds, 0.0, 0.0)
        h.settle()
        n = len(cmds)
        h.settle()
        assert len(cmds) == n
