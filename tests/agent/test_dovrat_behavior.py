"""dovrat_swarm through a BMA on memq://: detection from both sources, direction, zero on stop."""

from __future__ import annotations

import json
import time
from typing import Any

import pytest

from antalate_lcm.msgs import direction_cmd_t, payload_t, peer_detection_t, telemetry_t, velocity_cmd_t
from tests.harness.bma import AGENT, Harness, harness, make_config
from tests.harness.polling import wait_for

PARAMS = {"forward_speed": 2.0, "gentle_turn_rate": 10.0, "sharp_turn_rate": 45.0, "detection_timeout": 0.4}


def _config(params: dict[str, Any] | None = None, **extra: Any) -> Any:
    behavior = {"plugin": "dovrat_swarm", "params": {**PARAMS, **(params or {})}, "tick_hz": 50.0}
    return make_config([{"name": "swarm", "behaviors": [behavior]}], **extra)


def _latest(cmds: list[velocity_cmd_t], h: Harness) -> velocity_cmd_t:
    h.settle()
    return cmds[-1]


def _peer(h: Harness, detected: bool) -> None:
    msg = peer_detection_t()
    msg.detected, msg.count, msg.nearest_range = detected, int(detected), 12.0 if detected else 0.0
    h.probe.publish("PEER_DETECTION", msg)


def _payload(h: Harness, obj: Any) -> None:
    msg = payload_t()
    msg.content_type = "application/json"
    msg.data = json.dumps(obj).encode()
    msg.size = len(msg.data)
    h.probe.publish("OPERATOR_PAYLOAD", msg)


def _direction(
    h: Harness,
    azimuth: float,
    speed: float,
    *,
    target: str = "",
    topic: str = "SWARM_DIRECTION_CMD",
    active: bool = True,
    unsigned: bool = False,
) -> None:
    """A direction from the probe node (signed by Node.publish when the config has a key)."""
    msg = direction_cmd_t()
    msg.active, msg.azimuth, msg.speed, msg.target = active, azimuth, speed, target
    if unsigned:  # what an attacker without the key can send: a fresh header, no MAC
        msg.header.utime, msg.header.agent, msg.header.seq = int(time.time() * 1e6), "attacker", 1
        h.context.buses.publish("lan", h.probe.channel(topic), msg.encode())
    else:
        h.probe.publish(topic, msg)


def _heading(h: Harness, heading: float) -> None:
    msg = telemetry_t()
    msg.heading = heading
    h.probe.publish("TELEMETRY", msg)


def _yaw_becomes(cmds: list[velocity_cmd_t], rate: float, timeout: float = 2.0) -> bool:
    return bool(wait_for(lambda: cmds and cmds[-1].yaw_rate == pytest.approx(rate), timeout))


def test_flies_forward_turning_sharply_with_no_peer_and_gently_with_one() -> None:
    with harness(_config()) as h:
        cmds = h.record("VELOCITY_CMD")
        node = h.bma("swarm")
        h.mc_state("STANDBY")
        h.settle()
        assert cmds == []  # only in MISSION
        h.mc_state("MISSION")
        assert _yaw_becomes(cmds, 45.0)
        cmd = cmds[-1]
        assert cmd.frame == velocity_cmd_t.BODY and cmd.vx == 2.0 and cmd.vy == 0.0 and cmd.vz == 0.0
        assert cmd.header.agent == AGENT

        _peer(h, True)
        assert _yaw_becomes(cmds, 10.0)
        _peer(h, False)
        assert _yaw_becomes(cmds, 45.0)
        _peer(h, True)
        assert _yaw_becomes(cmds, 10.0)
        t0 = time.monotonic()
        assert _yaw_becomes(cmds, 45.0)  # the detection goes stale after detection_timeout
        assert time.monotonic() - t0 >= 0.2
        assert h.sync(lambda: node.failures()) == {}


def test_detection_from_the_station_payload() -> None:
    with harness(_config()) as h:
        cmds = h.record("VELOCITY_CMD")
        h.bma("swarm")
        h.mc_state("MISSION")
        assert _yaw_becomes(cmds, 45.0)
        _payload(h, {"detected": True, "count": 1, "nearest_range": 30.0, "nearest_bearing": 4.0})
        assert _yaw_becomes(cmds, 10.0)
        _payload(h, {"detected": False, "count": 0, "nearest_range": 0.0, "nearest_bearing": 0.0})
        assert _yaw_becomes(cmds, 45.0)
        _payload(h, {"something": "else"})  # not a detection: ignored, not a failure
        h.settle()
        assert cmds[-1].yaw_rate == 45.0


def test_detection_source_restricts_the_inputs() -> None:
    with harness(_config({"detection_source": "peer_detection"})) as h:
        cmds = h.record("VELOCITY_CMD")
        h.bma("swarm")
        h.mc_state("MISSION")
        assert _yaw_becomes(cmds, 45.0)
        _payload(h, {"detected": True})
        time.sleep(0.1)
        assert _latest(cmds, h).yaw_rate == 45.0
        _peer(h, True)
        assert _yaw_becomes(cmds, 10.0)


def test_operator_direction_is_blended_and_targeting_is_respected() -> None:
    with harness(_config()) as h:
        cmds = h.record("VELOCITY_CMD")
        h.bma("swarm")
        _direction(h, 90.0, 3.0)  # set while still on the ground: remembered
        h.mc_state("MISSION")
        _heading(h, 0.0)
        assert wait_for(lambda: cmds and cmds[-1].vy == pytest.approx(3.0))
        assert cmds[-1].vx == pytest.approx(2.0) and cmds[-1].yaw_rate == 45.0

        _direction(h, 180.0, 1.0, target="someone-else", topic="DIRECTION_CMD")
        time.sleep(0.1)
        assert _latest(cmds, h).vy == pytest.approx(3.0)  # not for us
        _direction(h, 180.0, 1.0, target=AGENT, topic="DIRECTION_CMD")
        assert wait_for(lambda: cmds[-1].vx == pytest.approx(1.0) and abs(cmds[-1].vy) < 1e-6)
        _direction(h, 0.0, 0.0, active=False)
        assert wait_for(lambda: cmds[-1].vx == pytest.approx(2.0) and cmds[-1].vy == 0.0)


def test_deactivation_sends_one_zero_velocity() -> None:
    with harness(_config()) as h:
        cmds = h.record("VELOCITY_CMD")
        h.bma("swarm")
        h.mc_state("MISSION")
        assert wait_for(lambda: len(cmds) >= 3)
        h.mc_state("RTL")
        assert wait_for(lambda: cmds[-1].vx == 0.0 and cmds[-1].yaw_rate == 0.0)
        n = len(cmds)
        time.sleep(0.15)
        h.settle()
        assert len(cmds) == n


def test_unsigned_direction_rejected_when_a_swarm_key_is_set() -> None:
    key = "k3y"
    with harness(_config(security={"swarm_key": key})) as h:
        cmds = h.record("VELOCITY_CMD")
        h.bma("swarm")
        h.mc_state("MISSION")
        _heading(h, 0.0)
        _direction(h, 90.0, 3.0, unsigned=True)
        time.sleep(0.15)
        assert _latest(cmds, h).vy == 0.0
        _direction(h, 90.0, 3.0)
        assert wait_for(lambda: cmds[-1].vy == pytest.approx(3.0))
