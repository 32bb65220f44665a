"""Validate config tables the way TOML types them: no silent coercion, one error naming the key.

A field trial showed ``'5'`` becoming 5 and ``'yes'`` becoming True: pydantic's default (lax) mode
guesses, and a guess in a flight config is a vehicle doing something nobody wrote. Every table of the
config -- antalate's own sections, a vehicle adapter's params, a behavior's params -- goes
through :func:`validate_strict`, which validates in pydantic's *strict JSON* mode:

- a string is never a number or a boolean, a number never a boolean or a string;
- an integer is still fine where a float is expected (``rate = 2``);
- a TOML array fills a ``list`` or a ``tuple``, a string fills an ``Enum`` or a ``Path``: what a
  TOML (like a JSON) document can express is accepted as written, whatever the model's own mode;
- a TOML date or time is refused anywhere (no antalate setting is one; as a string it would slip
  into a text field unnoticed);
- a boolean does not fill an integer ``Literal`` (pydantic takes ``true`` for ``Literal[1, -1]``
  because ``True == 1``: a ``turn_direction = true`` would turn clockwise without a word).
"""

from __future__ import annotations

import datetime as _dt
import json
import types
from collections.abc import Mapping
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

from pydantic import BaseModel, ValidationError

from antalate_lcm.base.errors import StrictError as StrictError

M = TypeVar("M", bound=BaseModel)


def dotted(loc: tuple[Any, ...] | list[Any]) -> str:
    """``("bma", 0, "name")`` -> ``"bma[0].name"``; pydantic's validator tags are left out."""
    parts: list[str] = []
    for item in loc:
        if isinstance(item, int):
            parts[-1:] = [f"{parts[-1]}[{item}]"] if parts else [f"[{item}]"]
        elif str(item).startswith("function-"):
            continue
        else:
            parts.append(str(item))
    return ".".join(parts)


def find_datetime(data: Any, path: tuple[Any, ...] = ()) -> tuple[Any, ...] | None:
    """The location of the first TOML date/time in ``data``, or None."""
    if isinstance(data, _dt.date | _dt.time):  # datetime is a date
        return path
    if isinstance(data, Mapping):
        items: Any = data.items()
    elif isinstance(data, list | tuple):
        items = enumerate(data)
    else:
        return None
    for key, value in items:
        found = find_datetime(value, (*path, key))
        if found is not None:
            return found
    return None


def describe(exc: ValidationError) -> StrictError:
    """The first error of ``exc`` as a :class:`StrictError` (one line: key, what is wrong, the value)."""
    err = exc.errors()[0]
    key = dotted(tuple(err["loc"]))
    got = err.get("input")
    shown = "" if isinstance(got, dict) or err["type"] == "missing" else f", got {got!r}"
    return StrictError(key, f"{err['msg']}{shown}")


def _int_literals(annotation: Any) -> tuple[Any, ...]:
    """The members of the ``Literal``s in ``annotation`` (through ``X | None``) if some are ints and none bools."""
    origin = get_origin(annotation)
    if origin is Literal:
        members: tuple[Any, ...] = get_args(annotation)
    elif origin in (Union, types.UnionType):
        members = tuple(m for arg in get_args(annotation) for m in _int_literals(arg))
    else:
        return ()
    has_int = any(isinstance(m, int) and not isinstance(m, bool) for m in members)
    return members if has_int and not any(isinstance(m, bool) for m in members) else ()


def _bool_for_int_literal(
    model: type[BaseModel], data: Mapping[str, Any], path: tuple[Any, ...] = ()
) -> None:
    for name, info in model.model_fields.items():
        key = info.alias or name
        if key not in data:
            continue
        value = data[key]
        members = _int_literals(info.annotation)
        if isinstance(value, bool) and members:
            expected = " or ".join(repr(m) for m in members)
            raise StrictError(dotted((*path, key)), f"Input should be {expected}, got {value!r}")
        if (
            isinstance(value, Mapping)
            and isinstance(info.annotation, type)
            and issubclass(info.annotation, BaseModel)
        ):
            _bool_for_int_literal(info.annotation, value, (*path, key))


def validate_strict(model: type[M], data: Mapping[str, Any]) -> M:
    """``model`` validated from ``data`` (a TOML table) in strict JSON mode; raises :class:`StrictError`."""
    where = find_datetime(data)
    if where is not None:
        raise StrictError(dotted(where), "a TOML date/time is not a valid value here")
    _bool_for_int_literal(model, data)
    try:
        text = json.dumps(dict(data), allow_nan=True)
    except (TypeError, ValueError) as exc:  # a Python caller's object that TOML cannot hold
        raise StrictError("", f"not a TOML table: {exc}") from None
    try:
        return model.model_validate_json(text, strict=True)
    except ValidationError as exc:
        raise describe(exc) from None


__all__ = ["StrictError", "describe", "dotted", "find_datetime", "validate_strict"]
