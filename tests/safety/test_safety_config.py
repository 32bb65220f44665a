"""[safety] in the config: per-vehicle defaults, and every bad value named by its key before anything flies."""

from __future__ import annotations

from typing import Any

import pytest

from antalate_lcm.agent.hlc.safety import SafetyLayer, filter_params
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.base.safety.filter import Policy
from antalate_lcm.core.config import parse_config

ORIGIN = [32.7767, 35.0231]
SQUARE = [[0.0, 0.0], [0.0, 40.0], [40.0, 40.0], [40.0, 0.0]]


@pytest.mark.parametrize(
    ("safety", "key", "expected"),
    [
        ({"radius": 0.0}, "safety.radius", "greater than 0"),
        ({"radius": "3"}, "safety.radius", "number"),
        ({"gamma": -1.0}, "safety.gamma", "greater than 0"),
        ({"no_peers": "panic"}, "safety.no_peers", "hover"),
        ({"rtl": "teleport"}, "safety.rtl", "filtered"),
        ({"min_peers": -1}, "safety.min_peers", "greater than or equal to 0"),
        ({"stale_after": 5.0, "forget_after": 2.0}, "safety.forget_after", "at least stale_after"),
        ({"origin": [95.0, 0.0]}, "safety.origin", "[lat, lon]"),
        ({"fence": {"polygon": SQUARE}}, "safety.origin", "needs its origin"),
        ({"fence": {}}, "safety.fence.polygon", "either polygon"),
        (
            {"origin": ORIGIN, "fence": {"polygon": SQUARE, "polygon_wgs84": [ORIGIN, ORIGIN, ORIGIN]}},
            "safety.fence.polygon",
            "not both",
        ),
        (
            {"origin": ORIGIN, "fence": {"polygon": [[0.0, 0.0], [10.0, 10.0], [10.0, 0.0], [0.0, 5.0]]}},
            "safety.fence.polygon",
            "crosses itself",
        ),
        ({"origin": ORIGIN, "fence": {"polygon": [[0.0, 0.0], [1.0]]}}, "safety.fence.polygon", ""),
        (
            {"origin": ORIGIN, "fence": {"polygon": SQUARE, "floor": 10.0, "ceiling": 5.0}},
            "safety.fence.polygon",
            "below its ceiling",
        ),
        (
            {"fence": {"polygon_wgs84": [[91.0, 0.0], [0.0, 1.0], [1.0, 1.0]]}},
            "safety.fence.polygon_wgs84",
            "",
        ),
        (
            {"fence": {"polygon": SQUARE, "outside": "explode"}, "origin": ORIGIN},
            "safety.fence.outside",
            "return",
        ),
        ({"radious": 3.0}, "safety.radious", "Extra inputs"),
    ],
)
def test_bad_safety_tables_name_the_key(safety: dict[str, Any], key: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config({"safety": safety}, "swarm.toml")
    assert f": {key}" in str(info.value) or key in str(info.value), str(info.value)
    assert expected in str(info.value)


@pytest.mark.parametrize(
    ("autopilot", "radius", "vertical"), [("sim", 3.0, 1.5), ("crazyflie", 0.4, 0.3), ("tello", 1.0, 0.5)]
)
def test_per_vehicle_defaults(autopilot: str, radius: float, vertical: float) -> None:
    params: dict[str, Any] = {"uri": "radio://0/80/2M/E7E7E7E7E7"} if autopilot == "crazyflie" else {}
    config = parse_config({"hlc": {"autopilot": autopilot, "autopilot_params": params}}, "x.toml")
    p = filter_params(config)
    assert (p.separation.radius, p.separation.vertical) == (radius, vertical)
    assert p.separation.peer_speed == config.hlc.max_horizontal_speed


def test_explicit_values_win_and_the_sim_lead_is_its_tau() -> None:
    config = parse_config(
        {
            "hlc": {"autopilot": "sim", "autopilot_params": {"tau": 0.3}},
            "safety": {"radius": 5.0, "vertical": 2.5, "no_peers": "land", "min_peers": 2},
        },
        "x.toml",
    )
    p = filter_params(config)
    assert (p.separation.radius, p.separation.vertical, p.separation.lead) == (5.0, 2.5, 0.3)
    assert p.no_peers is Policy.LAND and p.min_peers == 2


def test_a_wgs84_fence_is_placed_in_the_local_frame() -> None:
    corners = [[32.7760, 35.0220], [32.7760, 35.0240], [32.7780, 35.0240], [32.7780, 35.0220]]
    config = parse_config(
        {"safety": {"enabled": True, "origin": ORIGIN, "fence": {"polygon_wgs84": corners}}}, "x"
    )
    layer = SafetyLayer("a", config)
    fence = layer.params.fence
    assert fence is not None
    assert fence.inside_polygon(0.0, 0.0)
    north, east = fence.polygon[0]
    assert north == pytest.approx(-77.6, abs=0.5) and east == pytest.approx(-102.8, abs=0.5)
