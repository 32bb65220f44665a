"""Config-load validation of [[bma]]: every mistake fails before any node starts, naming the key."""

from __future__ import annotations

import contextlib
from typing import Any

import pytest
from pydantic import BaseModel, ConfigDict

from antalate_lcm.agent.bma import BmaNode, plan_bma, validate_bma_config
from antalate_lcm.agent.bma.plan import shared_params_model
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.base.strict import validate_strict
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.node import Context
from behaviors.dovrat_swarm.behavior import DovratSwarm
from tests.harness.bma import make_config

REC = "tests.harness.bma:Recorder"
SWITCHER = "tests.harness.bma:ModeSwitcher"
SWARM_MODE = {"SWARM_MODE": {"type": "behavior_state_t", "channel": "{agent}/SWARM_MODE"}}


def _fails(bma: list[dict[str, Any]], key: str, *fragments: str, **extra: Any) -> ConfigError:
    config = make_config(bma, **extra)
    with pytest.raises(ConfigError) as info:
        validate_bma_config(config)
    err = info.value
    assert err.key == key, err
    assert err.file == "test.toml"
    for fragment in fragments:
        assert fragment in err.expected, err.expected
    return err


def test_a_good_config_validates_and_plans() -> None:
    config = make_config(
        [
            {"name": "ops", "behaviors": [{"plugin": "auto_operator", "params": {"rtl_after": 60}}]},
            {
                "name": "swarm",
                "behaviors": [
                    {"plugin": "dovrat_swarm", "params": {"forward_speed": 3, "turn_direction": -1}},
                    {"plugin": REC, "activate_on": ["MISSION"], "deactivate_on": ["STANDBY"], "tick_hz": 4},
                ],
            },
        ]
    )
    validate_bma_config(config)
    plan = plan_bma(config, config.bma[1])
    swarm, rec = plan.behaviors
    assert swarm.name == "dovrat_swarm" and swarm.tick_hz == 10.0  # the plugin's defaults
    assert swarm.rule.activate_on == {"MISSION"} and swarm.params.forward_speed == 3  # type: ignore[attr-defined]
    assert swarm.topics["VELOCITY_CMD"] == "VELOCITY_CMD"
    assert rec.name == "Recorder" and rec.tick_hz == 4 and rec.rule.deactivate_on == {"STANDBY"}
    ops = plan_bma(config, config.bma[0]).behaviors[0]
    assert ops.rule.activate_on == {"STANDBY", "MISSION"}


def test_unknown_plugin() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "auto_operater"}]}],
        "bma[0].behaviors[0].plugin",
        "no plugin 'auto_operater'",
        "auto_operator",
        "dovrat_swarm",
    )


def test_unimportable_module_class() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "no_such_module:Thing", "activate_on": ["MISSION"]}]}],
        "bma[0].behaviors[0].plugin",
        "cannot load 'no_such_module:Thing'",
    )


def test_plugin_that_is_not_a_behavior() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "antalate_lcm.core.config:Config"}]}],
        "bma[0].behaviors[0].plugin",
        "not a subclass of antalate_lcm.core.behavior.Behavior",
    )


def test_bad_param_value() -> None:
    _fails(
        [
            {
                "name": "m",
                "behaviors": [
                    {"plugin": REC, "activate_on": ["MISSION"]},
                    {"plugin": "dovrat_swarm", "params": {"forward_speed": "fast"}},
                ],
            }
        ],
        "bma[0].behaviors[1].params.forward_speed",
        "valid number",
        "'fast'",
    )


def test_param_out_of_range_and_unknown_param() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "auto_operator", "params": {"retry": 0}}]}],
        "bma[0].behaviors[0].params.retry",
        "greater than 0",
    )
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "auto_operator", "params": {"rtl_afterr": 5}}]}],
        "bma[0].behaviors[0].params.rtl_afterr",
        "Extra inputs are not permitted",
    )


def test_missing_required_param() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "video_capture"}]}],
        "bma[0].behaviors[0].params.input",
        "Field required",
    )


def test_unknown_mc_state() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": REC, "activate_on": ["MISSION", "HOVER"]}]}],
        "bma[0].behaviors[0].activate_on[1]",
        "an mc_state_t state",
        "STANDBY",
        "'HOVER'",
    )
    _fails(
        [
            {
                "name": "m",
                "behaviors": [{"plugin": REC, "activate_on": ["MISSION"], "deactivate_on": ["mission"]}],
            }
        ],
        "bma[0].behaviors[0].deactivate_on[0]",
        "'mission'",
    )


def test_state_in_both_lists_and_no_state_at_all() -> None:
    _fails(
        [
            {
                "name": "m",
                "behaviors": [{"plugin": REC, "activate_on": ["MISSION"], "deactivate_on": ["MISSION"]}],
            }
        ],
        "bma[0].behaviors[0].deactivate_on[0]",
        "in both",
    )
    _fails(
        [{"name": "m", "behaviors": [{"plugin": REC}]}],
        "bma[0].behaviors[0].activate_on",
        "at least one state",
    )


def test_cascaded_states_are_free_unless_declared() -> None:
    free = [
        {
            "name": "m",
            "state_topic": "SWARM_MODE",
            "behaviors": [{"plugin": REC, "activate_on": ["ANYTHING"]}],
        }
    ]
    validate_bma_config(make_config(free, topics=SWARM_MODE))
    declared = [
        {
            "name": "m",
            "state_topic": "SWARM_MODE",
            "states": ["SEARCH", "FOLLOW"],
            "behaviors": [{"plugin": REC, "activate_on": ["SEARCH", "FOLOW"]}],
        }
    ]
    _fails(declared, "bma[0].behaviors[0].activate_on[1]", "SEARCH, FOLLOW", "'FOLOW'", topics=SWARM_MODE)


def test_declared_states_of_an_mc_arbiter_must_be_mc_states() -> None:
    _fails([{"name": "m", "states": ["FLYING"], "behaviors": []}], "bma[0].states[0]", "'FLYING'")


def test_state_topic_of_the_wrong_type() -> None:
    _fails(
        [{"name": "m", "state_topic": "TELEMETRY", "behaviors": []}],
        "bma[0].state_topic",
        "mc_state_t or behavior_state_t",
        "telemetry_t",
    )


def test_duplicate_behavior_names() -> None:
    _fails(
        [
            {
                "name": "m",
                "behaviors": [
                    {"plugin": REC, "activate_on": ["MISSION"]},
                    {"plugin": REC, "activate_on": ["STANDBY"]},
                ],
            }
        ],
        "bma[0].behaviors[1].name",
        "'Recorder'",
        "behaviors[0]",
    )


def test_topic_remap_to_an_unknown_topic() -> None:
    _fails(
        [
            {
                "name": "m",
                "behaviors": [
                    {"plugin": SWITCHER, "activate_on": ["MISSION"], "topics": {"MODE": "SWARM_MOOD"}}
                ],
            }
        ],
        "bma[0].behaviors[0].topics.MODE",
        "'SWARM_MOOD'",
        topics=SWARM_MODE,
    )


def test_topic_remap_of_a_topic_the_behavior_does_not_use() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": "dovrat_swarm", "topics": {"TELEMETRI": "TELEMETRY"}}]}],
        "bma[0].behaviors[0].topics.TELEMETRI",
        "VELOCITY_CMD",
    )


def test_topic_remap_to_the_wrong_type() -> None:
    _fails(
        [
            {
                "name": "m",
                "behaviors": [
                    {"plugin": SWITCHER, "activate_on": ["MISSION"], "topics": {"MODE": "TELEMETRY"}}
                ],
            }
        ],
        "bma[0].behaviors[0].topics.MODE",
        "behavior_state_t",
        "telemetry_t",
    )


def test_behavior_topic_without_a_binding() -> None:
    _fails(
        [{"name": "m", "behaviors": [{"plugin": SWITCHER, "activate_on": ["MISSION"]}]}],
        "bma[0].behaviors[0].topics",
        "'MODE'",
        "[topics]",
    )


def test_a_remap_to_a_new_topic_of_the_same_type_is_fine() -> None:
    topics = {"SIM_DETECTION": {"type": "peer_detection_t", "channel": "{agent}/SIM_DETECTION"}}
    config = make_config(
        [
            {
                "name": "m",
                "behaviors": [{"plugin": "dovrat_swarm", "topics": {"PEER_DETECTION": "SIM_DETECTION"}}],
            }
        ],
        topics=topics,
    )
    validate_bma_config(config)
    assert plan_bma(config, config.bma[0]).behaviors[0].topics["PEER_DETECTION"] == "SIM_DETECTION"


def test_bma_node_refuses_a_bad_config_at_construction() -> None:
    config = make_config([{"name": "m", "behaviors": [{"plugin": "nope"}]}])
    with (
        contextlib.closing(Context(Buses(config.buses), Executor())) as context,
        pytest.raises(ConfigError, match=r"bma\[0\].behaviors\[0\].plugin"),
    ):
        BmaNode(config, context, config.bma[0])


def test_equal_frozen_params_are_one_object_and_nothing_else_is_shared() -> None:
    """`shared_params_model`: agents planned from one config read one params object; the model it
    stands in for is the one validated (equal, the same fields set), and a model that differs in a
    bit (-0.0), in the fields set, or is not frozen or hashable, stays the behavior's own."""
    bma = [{"name": "swarm", "behaviors": [{"plugin": "dovrat_swarm", "params": {"forward_speed": 3.0}}]}]
    first, second = (plan_bma(c, c.bma[0]).behaviors[0].params for c in (make_config(bma), make_config(bma)))
    assert first is second
    own = validate_strict(DovratSwarm.Params, {"forward_speed": 3.0})
    assert own == first and own.model_fields_set == first.model_fields_set and own is not first

    def shared(model: type[BaseModel], **values: Any) -> BaseModel:
        return shared_params_model(model(**values))

    P = DovratSwarm.Params
    assert shared(P, max_speed=1.0) is shared(P, max_speed=1.0)
    assert shared(P, max_speed=0.0) is not shared(P, max_speed=-0.0)  # equal, not the same bits
    assert shared(P, forward_speed=2.0) is not shared(P)  # equal, but one says it was set

    class Loose(BaseModel):
        speeds: list[float] = [1.0]

    class FrozenList(BaseModel):
        model_config = ConfigDict(frozen=True)
        speeds: list[float] = [1.0]

    assert shared(Loose) is not shared(Loose)
    assert shared(FrozenList) is not shared(FrozenList)
