"""The package's small public API resolves, and lists exactly what it exports."""

from __future__ import annotations

import antalate_lcm


def test_every_public_name_resolves() -> None:
    assert set(antalate_lcm.__all__) - {"__version__"} == set(antalate_lcm._EXPORTS)
    for name in antalate_lcm.__all__:
        assert getattr(antalate_lcm, name) is not None


def test_unknown_name_is_an_attribute_error() -> None:
    import pytest

    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        antalate_lcm.Nope  # type: ignore[attr-defined]  # noqa: B018
