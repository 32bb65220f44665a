"""The wire vocabulary is exactly the generated types' constants, and the only place they are named."""

from __future__ import annotations

import enum
from typing import Any, get_args

import pytest

from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t, operator_cmd_t
from antalate_lcm.wire.vocabulary import (
    Command,
    CommandName,
    HlcState,
    HlcStateName,
    McState,
    McStateName,
    Severity,
    member_of,
    name_of,
    names,
)

VOCABULARY: list[tuple[type[enum.IntEnum], type]] = [
    (McState, mc_state_t),
    (HlcState, hlc_state_t),
    (Command, operator_cmd_t),
    (Severity, hlc_error_t),
]


def _constants(msg_type: type) -> dict[str, int]:
    """What lcm-gen made of the ``.lcm`` file's ``const`` lines (upper-case int class attributes)."""
    return {
        name: value
        for name, value in vars(msg_type).items()
        if name.isupper() and isinstance(value, int) and not isinstance(value, bool)
    }


@pytest.mark.parametrize(("kind", "msg_type"), VOCABULARY, ids=lambda x: x.__name__)
def test_enum_is_exactly_the_generated_constants(kind: type[enum.IntEnum], msg_type: type) -> None:
    """A constant added to (or removed from) the .lcm file fails here until the enum follows it."""
    assert {m.name: m.value for m in kind} == _constants(msg_type)


@pytest.mark.parametrize(
    ("literal", "kind"), [(McStateName, McState), (HlcStateName, HlcState), (CommandName, Command)], ids=str
)
def test_json_name_literals_are_the_enum_names(literal: Any, kind: type[enum.IntEnum]) -> None:
    assert get_args(literal) == names(kind)


def test_name_of_copes_with_undefined_values() -> None:
    assert name_of(McState, mc_state_t.MISSION) == "MISSION"
    assert name_of(HlcState, hlc_state_t.AIRBORNE) == "AIRBORNE"
    assert name_of(Command, operator_cmd_t.RTL) == "RTL"
    assert name_of(Severity, hlc_error_t.CRITICAL) == "CRITICAL"
    assert name_of(McState, 99) is None  # a newer agent's state, or a corrupt message
    assert name_of(McState, -1) is None
    assert name_of(HlcState, None) is None  # nothing heard yet


@pytest.mark.parametrize("kind", [McState, HlcState, Command, Severity])
@pytest.mark.parametrize("value", [*range(-2, 20), None, 3.0, 3.5, True, "3", b"\x03", (3,), [3], {3: 3}])
def test_member_of_is_the_enums_own_answer(kind: type[enum.IntEnum], value: object) -> None:
    """A wire value's member from a table, as ``kind(value)`` gives it, None where that raises
    (an unhashable value too): what the BMA, the MC and the scripted operator ask per message."""
    try:
        expected: enum.IntEnum | None = kind(value)  # type: ignore[arg-type]  # any value a message may carry
    except (ValueError, TypeError):
        expected = None
    assert member_of(kind, value) is expected
    assert name_of(kind, value) == (None if expected is None else expected.name)  # type: ignore[arg-type]


def test_names_are_in_wire_order() -> None:
    assert names(Severity) == ("INFO", "WARNING", "ERROR", "CRITICAL")
    assert names(McState)[0] == "INIT"


def test_station_models_use_the_vocabulary_literals() -> None:
    """The station's JSON validates states and commands with these very literals, not copies."""
    from antalate_lcm.station import models

    annotations: dict[str, object] = {
        "mc_state": models.ReportRequest.model_fields["mc_state"].annotation,
        "hlc_state": models.ReportRequest.model_fields["hlc_state"].annotation,
        "command": models.OperatorCommand.model_fields["command"].annotation,
    }
    assert annotations == {
        "mc_state": McStateName | None,
        "hlc_state": HlcStateName | None,
        "command": CommandName,
    }
