"""Encoding antalate's flat messages in one ``b"".join``, byte for byte what lcm-gen's ``encode`` writes.

lcm-gen's Python ``encode`` writes every field into a ``BytesIO``, one ``struct.pack`` and one
``write`` per field group, and asserts the header's fingerprint on the way: 3-4 µs per message
in a process of a thousand simulated agents, which publish 20 a second each (telemetry and their
MC and HLC states). For a type made of the ``header_t`` followed by primitives and strings (no
arrays, no other nested type) the encoder here packs each run of primitives with one precompiled
``struct`` and joins the parts once. Any other type keeps lcm-gen's ``encode``
(tests/wire/test_fastcodec.py checks both against lcm-gen for every message type).

The decoder is the mirror image, for the messages a process delivers to its own nodes (an agent's
MC and HLC states, 10 a second per agent, in memory): one ``unpack_from`` per run of primitives at
an offset into the bytes, where lcm-gen's ``decode`` reads a ``BytesIO`` field by field and builds a
default message (and header) first only to overwrite every field. The same fields and values, the
same ``ValueError`` for another type's fingerprint and ``struct.error`` for a truncated message.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Callable, Iterator
from typing import Any

#: LCM primitive -> struct format character (lcm-gen's own choices: a boolean is packed as "b").
_FORMAT = {
    "int8_t": "b",
    "int16_t": "h",
    "int32_t": "i",
    "int64_t": "q",
    "float": "f",
    "double": "d",
    "boolean": "b",
    "byte": "B",
}
_HEADER = "antalate_lcm.msgs.header_t"

Encoder = Callable[[Any], bytes]
_ENCODERS: dict[type, Encoder] = {}
Decoder = Callable[[bytes], Any]
_DECODERS: dict[type, Decoder] = {}
#: ``header_t`` on the wire: utime and the agent name's length (with its NUL), then seq and mac_len;
#: and the length that precedes every string.
_HEADER_HEAD = struct.Struct(">qI")
_HEADER_SEQ = struct.Struct(">ih")
_STRING_LEN = struct.Struct(">I")


def encoder(cls: type) -> Encoder:
    """The fastest byte-exact encoder of ``cls`` (its own ``encode`` when it is not a flat type)."""
    enc = _ENCODERS.get(cls)
    if enc is None:
        enc = _ENCODERS[cls] = _compile(cls) or cls.encode  # type: ignore[attr-defined]
    return enc


def encode(msg: Any) -> bytes:
    """``msg.encode()``, through :func:`encoder`."""
    enc = _ENCODERS.get(type(msg))
    return (enc or encoder(type(msg)))(msg)


def _compile(cls: type) -> Encoder | None:
    fields = _flat_fields(cls)
    if fields is None:
        return None
    env: dict[str, Any] = {
        "_fp": cls._get_packed_fingerprint(),  # type: ignore[attr-defined]
        "_head": _HEADER_HEAD.pack,
        "_seq": _HEADER_SEQ.pack,
        "_len": _STRING_LEN.pack,
    }
    lines = [
        "def encode(msg):",
        "    h = msg.header",
        "    a = h.agent.encode('utf-8')",
        "    m = h.mac_len",
    ]
    parts = [
        "_fp",
        "_head(h.utime, len(a) + 1)",
        "a",
        "b'\\0'",
        "_seq(h.seq, m)",
        "(bytes(h.mac[:m]) if m else b'')",
    ]
    for i, (packer, run) in enumerate(_runs(fields)):
        if packer is None:  # a string
            lines.append(f"    s{i} = msg.{run[0]}.encode('utf-8')")
            parts.extend((f"_len(len(s{i}) + 1)", f"s{i}", "b'\\0'"))
        else:
            name = f"_p{len(env)}"
            env[name] = packer.pack
            parts.append(f"{name}({', '.join(f'msg.{n}' for n in run)})")
    lines.append(f"    return b''.join(({', '.join(parts)}))")
    exec("\n".join(lines), env)  # noqa: S102 - source built above from the type's own field table
    fn: Encoder = env["encode"]
    return fn


def decoder(cls: type) -> Decoder:
    """The fastest decoder of ``cls``'s bytes (its own ``decode`` when it is not a flat type)."""
    dec = _DECODERS.get(cls)
    if dec is None:
        dec = _DECODERS[cls] = _compile_decoder(cls) or cls.decode  # type: ignore[attr-defined]
    return dec


def _flat_fields(cls: type) -> list[tuple[str, str]] | None:
    """(name, lcm type) of the fields after the header, when ``cls`` is the header and then
    primitives and strings only."""
    names: list[str] = list(getattr(cls, "__slots__", ()))
    types: list[str] = list(getattr(cls, "__typenames__", ()))
    dims: list[Any] = list(getattr(cls, "__dimensions__", ()))
    if not names or len(names) != len(types) or len(dims) != len(types):
        return None
    if getattr(cls, "_get_packed_fingerprint", None) is None:
        return None
    if names[0] != "header" or types[0] != _HEADER or any(d is not None for d in dims[1:]):
        return None
    fields = list(zip(names[1:], types[1:], strict=True))
    if any(t not in _FORMAT and t != "string" for _, t in fields):
        return None
    return fields


def _runs(fields: list[tuple[str, str]]) -> Iterator[tuple[struct.Struct | None, list[str]]]:
    """A flat type's fields in wire order as both compilers walk them: each run of primitives with
    the one ``struct`` that packs it, and each string alone (``None``: a length, then its bytes)."""
    for is_string, group in itertools.groupby(fields, key=lambda field: field[1] == "string"):
        run = list(group)
        if is_string:
            for name, _ in run:
                yield None, [name]
        else:
            yield struct.Struct(">" + "".join(_FORMAT[t] for _, t in run)), [name for name, _ in run]


def _compile_decoder(cls: type) -> Decoder | None:
    fields = _flat_fields(cls)
    if fields is None:
        return None
    from antalate_lcm.msgs import header_t

    env: dict[str, Any] = {
        "_fp": cls._get_packed_fingerprint(),  # type: ignore[attr-defined]
        "_new": object.__new__,
        "_C": cls,
        "_H": header_t,
        "_head": _HEADER_HEAD.unpack_from,
        "_seq": _HEADER_SEQ.unpack_from,
        "_len": _STRING_LEN.unpack_from,
    }
    # As lcm-gen's header_t._decode_one; a negative mac_len reads the rest (BytesIO.read(-n)).
    lines = [
        "def decode(data):",
        "    if data[:8] != _fp:",
        "        raise ValueError('Decode error')",
        "    h = _new(_H)",
        "    h.utime, n = _head(data, 8)",
        "    o = 20 + n",
        "    h.agent = data[20:o][:-1].decode('utf-8', 'replace')",
        "    h.seq, m = _seq(data, o)",
        "    o += 6",
        "    h.mac_len = m",
        "    if m < 0:",
        "        h.mac = data[o:]",
        "        o = len(data)",
        "    else:",
        "        h.mac = data[o:o + m]",
        "        o += m",
        "    msg = _new(_C)",
        "    msg.header = h",
    ]
    booleans = {name for name, typename in fields if typename == "boolean"}
    for packer, run in _runs(fields):
        if packer is None:  # a string
            lines.append("    n = _len(data, o)[0]")
            lines.append("    o += 4")
            lines.append(f"    msg.{run[0]} = data[o:o + n][:-1].decode('utf-8', 'replace')")
            lines.append("    o += n")
            continue
        name = f"_p{len(env)}"
        env[name] = packer.unpack_from
        lines.append(f"    v = {name}(data, o)")
        for k, field in enumerate(run):
            value = f"bool(v[{k}])" if field in booleans else f"v[{k}]"
            lines.append(f"    msg.{field} = {value}")
        lines.append(f"    o += {packer.size}")
    lines.append("    return msg")
    exec("\n".join(lines), env)  # noqa: S102 - source built above from the type's own field table
    fn: Decoder = env["decode"]
    return fn
