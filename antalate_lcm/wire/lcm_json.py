"""antalate's LCM messages as JSON, with a JSON Schema for each type read off the ``.lcm`` files.

Foxglove, PlotJuggler and the ``mcap`` tools read JSON-encoded MCAP channels field by field when
each channel carries a JSON Schema; deriving the schemas from the ``.lcm`` definitions (with the
reader the Go emitter uses, ``tools.lcm_parse``) keeps them, their field names and the units written in
the comments in step with the wire contract, with nothing to maintain by hand.

The encoding is lossless, so a JSON message turns back into the same LCM bytes (:func:`from_json`):
a ``byte`` array is base64 (JSON has no bytes), and a non-finite ``float``/``double`` — which a
hostile or broken sender can put on the bus and JSON numbers cannot hold — is the string ``"NaN"``,
``"Infinity"`` or ``"-Infinity"``.
"""

from __future__ import annotations

import base64
import functools
import math
from collections.abc import Callable
from typing import Any

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.msgs import header_t
from antalate_lcm.tools import codegen
from antalate_lcm.tools.lcm_parse import Member, Struct, parse_files
from antalate_lcm.wire.topics import MESSAGE_TYPES

#: The one schema encoding and message encoding the MCAP spec and the Foxglove protocol name for JSON.
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"
NON_FINITE = ("NaN", "Infinity", "-Infinity")

_INT_BITS = {"int8_t": 8, "int16_t": 16, "int32_t": 32, "int64_t": 64}


@functools.cache
def structs() -> dict[str, Struct]:
    """Every ``.lcm`` struct by its short name (``telemetry_t``), parsed once per process."""
    files = codegen.lcm_files()
    if not files:
        raise AntalateError(
            f"no .lcm files in {codegen.LCMTYPES_DIR}: this antalate was installed without its message "
            "definitions (rebuild the wheel from a checkout)"
        )
    return {s.name.short: s for s in parse_files(files).values()}


def lcm_text(type_name: str) -> str:
    """The ``.lcm`` source of a type: the schema of a channel that keeps the LCM bytes (``--raw``)."""
    return structs()[type_name].source.read_text(encoding="utf-8")


def _constants_note(struct: Struct, member: Member) -> str | None:
    """``INIT=0, STANDBY=1, ...`` for the member the struct's constants name: the only member of the
    constants' type (mc_state_t.state, hlc_error_t.severity), so a reader sees what a number means."""
    if not struct.constants or member.dimensions:
        return None
    kinds = {c.type for c in struct.constants}
    if kinds != {member.type.full}:
        return None
    if sum(1 for m in struct.members if m.type.full == member.type.full and not m.dimensions) != 1:
        return None
    return ", ".join(f"{c.name}={c.value}" for c in struct.constants)


def _primitive_schema(kind: str) -> dict[str, Any]:
    if kind in _INT_BITS:
        bits = _INT_BITS[kind]
        return {"type": "integer", "minimum": -(1 << (bits - 1)), "maximum": (1 << (bits - 1)) - 1}
    if kind == "byte":
        return {"type": "integer", "minimum": 0, "maximum": 255}
    if kind in ("float", "double"):
        return {"anyOf": [{"type": "number"}, {"enum": list(NON_FINITE)}]}
    if kind == "string":
        return {"type": "string"}
    return {"type": "boolean"}


def _member_schema(struct: Struct, member: Member) -> dict[str, Any]:
    if member.type.primitive:
        item = _primitive_schema(member.type.full)
    else:
        item = _struct_schema(structs()[member.type.short])
    schema = item
    if member.type.full == "byte" and len(member.dimensions) == 1:
        schema = {"type": "string", "contentEncoding": "base64"}
    else:
        for dim in reversed(member.dimensions):
            schema = {"type": "array", "items": schema}
            if not dim.variable:
                schema["minItems"] = schema["maxItems"] = int(dim.size, 0)
    notes = [n for n in (member.comment, _constants_note(struct, member)) if n]
    if notes:
        schema = {**schema, "description": "\n".join(notes)}
    return schema


def _struct_schema(struct: Struct) -> dict[str, Any]:
    # Nested structs are inlined, not $ref'd: Foxglove's JSON Schema reader resolves no references.
    return {
        "title": f"{struct.name.package}.{struct.name.short}",
        "description": struct.comment or "",
        "type": "object",
        "properties": {m.name: _member_schema(struct, m) for m in struct.members},
        "required": [m.name for m in struct.members],
    }


@functools.cache
def schema(type_name: str) -> dict[str, Any]:
    """The JSON Schema of an antalate type (``telemetry_t``): field names, the ``.lcm`` comments
    (units, meaning) as descriptions, integer ranges, fixed array lengths."""
    try:
        struct = structs()[type_name]
    except KeyError:
        raise AntalateError(f"no .lcm definition of {type_name!r}") from None
    return _struct_schema(struct)


def schema_name(type_name: str) -> str:
    """The name a channel's schema goes by (``antalate_lcm.msgs.telemetry_t``, the .lcm package)."""
    s = structs()[type_name]
    return f"{s.name.package}.{s.name.short}"


#: The primitives JSON holds as they are (but for a float's non-finite values), each by the Python type
#: that both ways of the conversion coerce to.
_SAME_IN_JSON: dict[str, Callable[[Any], Any]] = {
    "boolean": bool,
    "string": str,
    "byte": int,
    **dict.fromkeys(_INT_BITS, int),
}


def _value_to_json(kind: str, value: Any) -> Any:
    if kind in ("float", "double"):
        f = float(value)
        if math.isfinite(f):
            return f
        return "NaN" if math.isnan(f) else ("Infinity" if f > 0 else "-Infinity")
    if kind in _SAME_IN_JSON:
        return _SAME_IN_JSON[kind](value)
    return to_json(value)


def _array_to_json(member: Member, value: Any, depth: int) -> Any:
    if depth == len(member.dimensions):
        return _value_to_json(member.type.short if not member.type.primitive else member.type.full, value)
    if member.type.full == "byte" and depth == len(member.dimensions) - 1:
        return base64.b64encode(bytes(value)).decode("ascii")
    return [_array_to_json(member, v, depth + 1) for v in value]


def to_json(msg: Any) -> dict[str, Any]:
    """A decoded antalate message as a JSON object, field by field in ``.lcm`` order."""
    struct = structs()[type(msg).__name__]
    return {m.name: _array_to_json(m, getattr(msg, m.name), 0) for m in struct.members}


def _value_from_json(kind: str, value: Any) -> Any:
    if kind in ("float", "double"):
        return float("nan") if value == "NaN" else float(value)  # "Infinity"/"-Infinity" parse as such
    if kind in _SAME_IN_JSON:
        return _SAME_IN_JSON[kind](value)
    return from_json(kind, value)


def _array_from_json(member: Member, value: Any, depth: int) -> Any:
    kind = member.type.full if member.type.primitive else member.type.short
    if depth == len(member.dimensions):
        return _value_from_json(kind, value)
    if member.type.full == "byte" and depth == len(member.dimensions) - 1:
        return base64.b64decode(value, validate=True)
    return [_array_from_json(member, v, depth + 1) for v in value]


def message_class(type_name: str) -> type[Any]:
    """The generated class of an antalate type, ``header_t`` included."""
    return header_t if type_name == "header_t" else MESSAGE_TYPES[type_name]


def from_json(type_name: str, data: dict[str, Any]) -> Any:
    """The message :func:`to_json` made (raises ``KeyError``/``ValueError``/``TypeError`` for an
    object that is not one: the caller counts it, as a log reader counts undecodable bytes)."""
    struct = structs()[type_name]
    msg = message_class(type_name)()
    for m in struct.members:
        setattr(msg, m.name, _array_from_json(m, data[m.name], 0))
    return msg
