"""An adapter's ``[hlc.autopilot_params]``: the one base model and the one parser every adapter uses.

A typo in a field config must fail at start-up naming the key, not fall back to a default in the air:
unknown keys are refused (``extra="forbid"``), types are strict (``"5"`` is not 5, ``true`` is not 1,
as `antalate_lcm.base.strict` reads a TOML table) and no float may be inf or nan (a timeout of inf never
fires). The constructor parses exactly as the config loader validates (`VehicleAdapter.validate_params`), so
a table that loads also constructs, and the error names the key the same way in both places.
"""

from __future__ import annotations

from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict

from antalate_lcm.base.strict import StrictError, validate_strict

__all__ = ["AdapterParams", "defaults", "parse_params", "require_duration"]


class AdapterParams(BaseModel):
    """Base of every adapter's params model: closed, strict, immutable, finite."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


P = TypeVar("P", bound=BaseModel)


def parse_params(model: type[P], raw: Any, adapter: str) -> P:
    """`model` from the config table `raw`; `ValueError` naming `adapter` and the key on anything wrong.

    An unknown key also lists the known ones, so a misspelt name is a one-line fix.
    """
    try:
        return validate_strict(model, dict(raw or {}))
    except StrictError as exc:
        where = f"parameter {exc.key!r}" if exc.key else "parameters"
        known = f" (known: {sorted(model.model_fields)})" if exc.message.startswith("Extra inputs") else ""
        raise ValueError(f"{adapter} autopilot {where}: {exc.message}{known}") from None


def defaults(model: type[BaseModel]) -> dict[str, Any]:
    """Every parameter of `model` with its default, by name (for docs and their checks)."""
    return {name: field.default for name, field in model.model_fields.items()}


def require_duration(key: str, value: float, minimum: float, shorter_than: str) -> None:
    """`ValueError` if the duration `key` (`value` s) is under `minimum` s, saying it is `shorter_than` what.

    For a model validator: a timer that watches a periodic stream (a link's staleness, a set-point's
    renewal) must span a few of its periods, or it fires on a healthy link.
    """
    if value < minimum:
        raise ValueError(f"{key} {value:g} s is shorter than {shorter_than}")
