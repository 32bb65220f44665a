"""Encoding antalate's messages in one ``b"".join``, byte for byte what lcm-gen's ``encode`` writes.

lcm-gen's Python ``encode`` writes every field into a ``BytesIO``, one ``struct.pack`` and one
``write`` per field group, and asserts the header's fingerprint on the way: 3-4 µs per message
in a process of a thousand simulated agents, which publish 25 a second each (telemetry, their MC,
HLC and BMA states). For a type made of the ``header_t`` followed by primitives, strings and
one-dimensional arrays of them sized by an earlier field (every type in lcmtypes/), the encoder
here packs each run of primitives with one precompiled ``struct`` and joins the parts once; an
array is written with lcm-gen's own expression for it. Any other type keeps lcm-gen's ``encode``
(tests/wire/test_fastcodec.py checks both against lcm-gen for every message type).

The decoder is the mirror image, for the messages a process delivers to its own nodes (an agent's
MC and HLC states, 10 a second per agent, in memory): one ``unpack_from`` per run of primitives at
an offset into the bytes, where lcm-gen's ``decode`` reads a ``BytesIO`` field by field and builds a
default message (and header) first only to overwrite every field. The same fields and values (an
array of primitives a tuple, of strings a list, of bytes ``bytes``, as lcm-gen's), the same
``ValueError`` for another type's fingerprint and ``struct.error`` for a truncated message.
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
#: The integer types an array's length may be.
_COUNTS = ("int8_t", "int16_t", "int32_t", "int64_t")
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

#: One field after the header: (kind, name, LCM type, the array's length field or "").
#: Kinds: "scalar" (a primitive), "string", "array" (of primitives other than byte and boolean),
#: "bytes" (an array of byte), "strings" (an array of string).
Field = tuple[str, str, str, str]


def encoder(cls: type) -> Encoder:
    """The fastest byte-exact encoder of ``cls`` (its own ``encode`` when it is not a type the
    compiler covers)."""
    enc = _ENCODERS.get(cls)
    if enc is None:
        enc = _ENCODERS[cls] = _compile(cls) or cls.encode  # type: ignore[attr-defined]
    return enc


def encode(msg: Any) -> bytes:
    """``msg.encode()``, through :func:`encoder`."""
    enc = _ENCODERS.get(type(msg))
    return (enc or encoder(type(msg)))(msg)


def _strings(values: Any, n: int) -> bytes:
    """lcm-gen's loop over a string array: the first ``n`` (an IndexError when there are fewer),
    each as its length (with the NUL), its UTF-8 and the NUL."""
    if n <= 0:  # (the count was packed before: an integer, or struct.error was raised there)
        return b""
    pack = _STRING_LEN.pack
    if n == 1:  # an arbiter's one active behavior
        s: bytes = values[0].encode("utf-8")
        return pack(len(s) + 1) + s + b"\0"
    parts: list[bytes] = []
    for i in range(n):
        s = values[i].encode("utf-8")
        parts += (pack(len(s) + 1), s, b"\0")
    return b"".join(parts)


def _read_strings(data: bytes, o: int, n: int) -> tuple[list[str], int]:
    """lcm-gen's decoding of a string array: ``n`` strings from offset ``o`` (none for n <= 0)."""
    out: list[str] = []
    unpack = _STRING_LEN.unpack_from
    for _ in range(n):
        k = unpack(data, o)[0]
        o += 4
        out.append(data[o : o + k][:-1].decode("utf-8", "replace"))
        o += k
    return out, o


def _compile(cls: type) -> Encoder | None:
    fields = _fields(cls)
    if fields is None:
        return None
    env: dict[str, Any] = {
        "_fp": cls._get_packed_fingerprint(),  # type: ignore[attr-defined]
        "_head": _HEADER_HEAD.pack,
        "_seq": _HEADER_SEQ.pack,
        "_len": _STRING_LEN.pack,
        "_pack": struct.pack,
        "_strings": _strings,
    }
    runs = list(_runs(fields))
    lines = [
        "def encode(msg):",
        "    h = msg.header",
        "    a = h.agent.encode('utf-8')",
        "    m = h.mac_len",
    ]
    parts: list[list[str]] = []
    for i, (packer, run) in enumerate(runs):
        kind, name, typename, count = run[0]
        if packer is not None:
            env[f"_p{i}"] = packer.pack
            parts.append([f"_p{i}({', '.join(f'msg.{f[1]}' for f in run)})"])
        elif kind == "string":
            lines.append(f"    s{i} = msg.{name}.encode('utf-8')")
            parts.append([f"_len(len(s{i}) + 1)", f"s{i}", "b'\\0'"])
        elif kind == "array":  # lcm-gen's expression, its errors included (a short list, a negative count)
            parts.append([f"_pack('>%d{_FORMAT[typename]}' % msg.{count}, *msg.{name}[:msg.{count}])"])
        elif kind == "bytes":
            parts.append([f"bytearray(msg.{name}[:msg.{count}])"])
        else:
            parts.append([f"_strings(msg.{name}, msg.{count})"])
    head = ["_fp", "_head(h.utime, len(a) + 1)", "a", "b'\\0'"]
    # Without a MAC (unsigned), seq and mac_len, the first run of primitives and the first string's
    # length lie side by side: one struct packs them.
    fused, args, k = _fused(runs)
    env["_fused"] = fused.pack
    first = [f"_fused(h.seq, m, {', '.join(args)})" if args else "_fused(h.seq, m)"]
    if k and runs[k - 1][0] is None:  # the string whose length was packed: its bytes and NUL
        first += parts[k - 1][1:]
    fast = [*head, *first, *(p for group in parts[k:] for p in group)]
    general = [
        *head,
        "_seq(h.seq, m)",
        "(bytes(h.mac[:m]) if m else b'')",
        *(p for group in parts for p in group),
    ]
    lines.append("    if m == 0:")
    lines.append(f"        return b''.join(({', '.join(fast)}))")
    lines.append(f"    return b''.join(({', '.join(general)}))")
    exec("\n".join(lines), env)  # noqa: S102 - source built above from the type's own field table
    fn: Encoder = env["encode"]
    return fn


def _fused(runs: list[tuple[struct.Struct | None, list[Field]]]) -> tuple[struct.Struct, list[str], int]:
    """The header's seq and mac_len, then the first run of primitives if one comes first, then the
    length of the string that follows if one does: one ``struct``, the field expressions after
    seq and mac_len, and how many of ``runs`` it covers (strings' lengths as ``s{i}``'s)."""
    fmt, args, k = ">ih", [], 0
    if k < len(runs) and runs[k][0] is not None:
        packer, run = runs[k]
        assert packer is not None
        fmt += packer.format[1:]
        args += [f"msg.{f[1]}" for f in run]
        k += 1
    if k < len(runs) and runs[k][0] is None and runs[k][1][0][0] == "string":
        fmt += "I"
        args.append(f"len(s{k}) + 1")
        k += 1
    return struct.Struct(fmt), args, k


def decoder(cls: type) -> Decoder:
    """The fastest decoder of ``cls``'s bytes (its own ``decode`` when it is not a type the
    compiler covers)."""
    dec = _DECODERS.get(cls)
    if dec is None:
        dec = _DECODERS[cls] = _compile_decoder(cls) or cls.decode  # type: ignore[attr-defined]
    return dec


def _fields(cls: type) -> list[Field] | None:
    """The fields after the header in wire order, when ``cls`` is the header and then primitives,
    strings, and one-dimensional arrays sized by an earlier integer field; else None."""
    names: list[str] = list(getattr(cls, "__slots__", ()))
    types: list[str] = list(getattr(cls, "__typenames__", ()))
    dims: list[Any] = list(getattr(cls, "__dimensions__", ()))
    if not names or len(names) != len(types) or len(dims) != len(types):
        return None
    if getattr(cls, "_get_packed_fingerprint", None) is None:
        return None
    if names[0] != "header" or types[0] != _HEADER or dims[0] is not None:
        return None
    fields: list[Field] = []
    counts: set[str] = set()
    for name, typename, dim in zip(names[1:], types[1:], dims[1:], strict=True):
        if dim is None:
            if typename == "string":
                fields.append(("string", name, typename, ""))
            elif typename in _FORMAT:
                fields.append(("scalar", name, typename, ""))
                if typename in _COUNTS:
                    counts.add(name)
            else:
                return None
            continue
        if len(dim) != 1 or dim[0] not in counts:  # fixed or multi-dimensional: lcm-gen's
            return None
        if typename == "string":
            fields.append(("strings", name, typename, dim[0]))
        elif typename == "byte":
            fields.append(("bytes", name, typename, dim[0]))
        elif typename in _FORMAT and typename != "boolean":
            fields.append(("array", name, typename, dim[0]))
        else:
            return None
    return fields


def _runs(fields: list[Field]) -> Iterator[tuple[struct.Struct | None, list[Field]]]:
    """The fields in wire order as both compilers walk them: each run of primitives with the one
    ``struct`` that packs it, and every other field alone (``None``)."""
    for scalar, group in itertools.groupby(fields, key=lambda field: field[0] == "scalar"):
        run = list(group)
        if scalar:
            yield struct.Struct(">" + "".join(_FORMAT[f[2]] for f in run)), run
        else:
            for f in run:
                yield None, [f]


def _compile_decoder(cls: type) -> Decoder | None:
    fields = _fields(cls)
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
        "_unpack": struct.unpack,
        "_strings": _read_strings,
    }
    runs = list(_runs(fields))
    for i, (packer, _) in enumerate(runs):
        if packer is not None:
            env[f"_p{i}"] = packer.unpack_from
    fused, _, k = _fused(runs)
    env["_fused"] = fused.unpack_from
    lines = [
        "def decode(data):",
        "    if data[:8] != _fp:",
        "        raise ValueError('Decode error')",
        "    h = _new(_H)",
        "    h.utime, n = _head(data, 8)",
        "    o = 20 + n",
        "    h.agent = data[20:o][:-1].decode('utf-8', 'replace')",
        "    msg = _new(_C)",
        "    msg.header = h",
        # Without a MAC (unsigned) and with the bytes there: seq, mac_len, the first run of
        # primitives and the first string's length in one unpack (what the encoder fused).
        f"    if len(data) >= o + {fused.size}:",
        "        v = _fused(data, o)",
        "        if v[1] == 0:",
        "            h.seq, h.mac_len, h.mac = v[0], 0, b''",
    ]
    at = 2
    if k and runs[0][0] is not None:
        lines += _assign(runs[0][1], "v", at, 12)
        at += len(runs[0][1])
    lines.append(f"            o += {fused.size}")
    if k and runs[k - 1][0] is None:  # the string whose length came with the rest
        lines += _read(runs[k - 1][1][0], k - 1, 12, length=f"v[{at}]")
    lines += [line for i in range(k, len(runs)) for line in _read(runs[i][1][0], i, 12, run=runs[i])]
    lines += [
        "            return msg",
        # As lcm-gen's header_t._decode_one; a negative mac_len reads the rest (BytesIO.read(-n)).
        "    h.seq, m = _seq(data, o)",
        "    o += 6",
        "    h.mac_len = m",
        "    if m < 0:",
        "        h.mac = data[o:]",
        "        o = len(data)",
        "    else:",
        "        h.mac = data[o:o + m]",
        "        o += m",
    ]
    # Past a truncated string or MAC, ``o`` may lie beyond the end: a slice there is empty, as
    # lcm-gen's read at the end of its BytesIO, and unpack_from raises struct.error, as its unpack
    # of a short read. An array of primitives is unpacked from a slice (lcm-gen's read), so an
    # empty one decodes even there; a negative count fails on its format, as lcm-gen's.
    lines += [line for i, item in enumerate(runs) for line in _read(item[1][0], i, 4, run=item)]
    lines.append("    return msg")
    exec("\n".join(lines), env)  # noqa: S102 - source built above from the type's own field table
    fn: Decoder = env["decode"]
    return fn


def _assign(run: list[Field], values: str, at: int, indent: int) -> list[str]:
    """A run of primitives' fields from ``values[at:]`` (a boolean as ``bool``, as lcm-gen's)."""
    pad = " " * indent
    return [
        f"{pad}msg.{name} = {f'bool({values}[{at + j}])' if typename == 'boolean' else f'{values}[{at + j}]'}"
        for j, (_, name, typename, _) in enumerate(run)
    ]


def _read(
    field: Field,
    i: int,
    indent: int,
    *,
    run: tuple[struct.Struct | None, list[Field]] | None = None,
    length: str | None = None,
) -> list[str]:
    """The decoder's lines for item ``i`` of the runs (``run``), or for a string whose ``length``
    was already read."""
    pad = " " * indent
    kind, name, typename, count = field
    if run is not None and run[0] is not None:
        return [f"{pad}v = _p{i}(data, o)", *_assign(run[1], "v", 0, indent), f"{pad}o += {run[0].size}"]
    if kind == "string":
        head = (
            [f"{pad}n = {length}"] if length is not None else [f"{pad}n = _len(data, o)[0]", f"{pad}o += 4"]
        )
        return [*head, f"{pad}msg.{name} = data[o:o + n][:-1].decode('utf-8', 'replace')", f"{pad}o += n"]
    if kind == "array":
        char = _FORMAT[typename]
        return [
            f"{pad}n = msg.{count} * {struct.calcsize('>' + char)}",
            f"{pad}msg.{name} = _unpack('>%d{char}' % msg.{count}, data[o:o + n])",
            f"{pad}o += n",
        ]
    if kind == "bytes":
        return [
            f"{pad}n = msg.{count}",
            f"{pad}msg.{name} = v = data[o:o + n] if n >= 0 else data[o:]",
            f"{pad}o += len(v)",
        ]
    return [f"{pad}msg.{name}, o = _strings(data, o, msg.{count})"]
