"""`base.shared.shared_value`: one instance per process of equal immutable values, by the value or a
caller's key, and no more kept past its bound."""

from __future__ import annotations

import pytest

from antalate_lcm.base import shared as shared_mod
from antalate_lcm.base.shared import shared_value


def test_equal_values_are_one_instance_and_a_key_tells_apart_what_equality_does_not() -> None:
    a, b = tuple([1.5, "x", ("nested",)]), tuple([1.5, "x", ("nested",)])  # (literals: one constant)
    assert a is not b and shared_value(a) is shared_value(b)
    zero, minus = tuple([0.0, 7.25]), tuple([-0.0, 7.25])  # equal, not the same bits
    assert shared_value(zero, key=("t", repr(zero))) is zero
    assert shared_value(minus, key=("t", repr(minus))) is minus
    with pytest.raises(TypeError):
        shared_value([1, 2])  # unhashable: a mutable value is never shared


def test_past_its_bound_it_keeps_nothing_more_and_still_answers(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(shared_mod, "_SHARED", {})
    monkeypatch.setattr(shared_mod, "_LIMIT", 2)
    first = shared_value(tuple([1]))
    shared_value(tuple([2]))
    late = tuple([3])
    assert shared_value(late) is late and shared_value(tuple([3])) is not late  # not kept
    assert shared_value(tuple([1])) is first  # what was kept still is
    assert len(shared_mod._SHARED) == 2
