"""antalate_lcm.wire.fastcodec writes exactly what lcm-gen's encode writes, for every message type."""

from __future__ import annotations

import random
import struct
from typing import Any

import pytest

import antalate_lcm.msgs as msgs
from antalate_lcm.wire.fastcodec import decoder, encode, encoder

TYPES = [
    getattr(msgs, name)
    for name in sorted(dir(msgs))
    if isinstance(getattr(msgs, name), type) and hasattr(getattr(msgs, name), "__typenames__")
]
#: lcm primitive -> a random value of it (booleans as bool, as lcm-gen decodes them).
_VALUES = {
    "int8_t": lambda r: r.randint(-128, 127),
    "int16_t": lambda r: r.randint(-(2**15), 2**15 - 1),
    "int32_t": lambda r: r.randint(-(2**31), 2**31 - 1),
    "int64_t": lambda r: r.randint(-(2**63), 2**63 - 1),
    "float": lambda r: r.uniform(-1e6, 1e6),
    "double": lambda r: r.uniform(-1e9, 1e9),
    "boolean": lambda r: r.random() < 0.5,
    "byte": lambda r: r.randint(0, 255),
    "string": lambda r: r.choice(["", "GUIDED", "b-001", "Zürich ✈", "x" * 300]),
}


def _fill(msg: Any, r: random.Random) -> None:
    """Random header and fields; an array's length field is set first (it precedes the array) and
    the array gets that many random elements (as a list, or bytes for a byte array); arrays that
    share a length field share its value."""
    counts: dict[str, int] = {}
    for name, typename, dim in zip(msg.__slots__, msg.__typenames__, msg.__dimensions__, strict=True):
        if name == "header":
            h = msg.header
            h.utime, h.seq = r.randint(0, 2**62), r.randint(0, 2**31 - 1)
            h.agent = r.choice(["", "b-001", "agent ünïcode"])
            h.mac_len = r.choice([0, 32])
            h.mac = bytes(r.randint(0, 255) for _ in range(h.mac_len))
        elif dim is not None:
            count = counts.setdefault(dim[0], r.choice([0, 1, 3, 17]))
            setattr(msg, dim[0], count)
            values = [_VALUES[typename](r) for _ in range(count)]
            setattr(msg, name, bytes(values) if typename == "byte" else values)
        elif typename in _VALUES:
            setattr(msg, name, _VALUES[typename](r))


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
def test_fast_encoding_is_lcm_gens_byte_for_byte(cls: type) -> None:
    r = random.Random(cls.__name__)
    for _ in range(50):
        msg = cls()
        _fill(msg, r)
        assert encode(msg) == msg.encode()
        assert type(msg).decode(encode(msg)).encode() == msg.encode()


def test_every_message_type_is_compiled_and_others_keep_lcm_gen() -> None:
    """Every type of lcmtypes/ that starts with the header (all but header_t itself) gets the fast
    encoder and decoder, its arrays included; a type the compiler does not cover (no header, a
    nested type, a fixed-size array) keeps lcm-gen's own."""
    for cls in TYPES:
        if cls is msgs.header_t:
            assert encoder(cls) is cls.encode and decoder(cls) is cls.decode
        else:
            assert encoder(cls) is not cls.encode and decoder(cls) is not cls.decode, cls

    class fixed_t(msgs.telemetry_t):  # noqa: N801 - as lcm-gen names its classes
        __dimensions__ = [None, None, None, None, None, None, None, None, None, ["3"], None, None]

    class nested_t(msgs.telemetry_t):  # noqa: N801
        __typenames__ = [*msgs.telemetry_t.__typenames__[:-1], "antalate_lcm.msgs.header_t"]

    for kept in (fixed_t, nested_t):
        assert encoder(kept) is kept.encode and decoder(kept) is kept.decode


def test_an_array_that_disagrees_with_its_count_fails_as_lcm_gen_fails() -> None:
    """Fewer elements than the count, or a negative count: the fast encoder raises what lcm-gen's
    raises, or writes the same bytes (a byte array is cut short by both, a string array of a
    negative count is empty in both)."""
    cases: list[tuple[Any, str, Any, str, int]] = [
        (msgs.arbiter_status_t(), "active", ["a", "b"], "n", 3),
        (msgs.arbiter_status_t(), "failed", ["a"], "n_failed", -2),
        (msgs.peer_scan_t(), "range", [1.0], "n", 2),
        (msgs.peer_scan_t(), "range", [], "n", -1),
        (msgs.payload_t(), "data", b"abc", "size", 5),
        (msgs.payload_t(), "data", b"abcdef", "size", -2),
        (msgs.payload_t(), "data", "text", "size", 4),
    ]
    for msg, name, values, count, n in cases:
        setattr(msg, name, values)
        setattr(msg, count, n)
        try:
            expected: Any = msg.encode()
        except Exception as exc:  # noqa: BLE001 - its type is what is compared
            expected = type(exc)
        try:
            got: Any = encode(msg)
        except Exception as exc:  # noqa: BLE001
            got = type(exc)
        assert got == expected, (type(msg).__name__, name, n)


def test_a_bad_field_fails_as_lcm_gen_fails() -> None:
    """A value the wire cannot carry raises in the fast encoder too (never a silently wrong datagram)."""
    msg = msgs.telemetry_t()
    msg.lat = "north"  # type: ignore[assignment]
    with pytest.raises(struct.error):
        msg.encode()
    with pytest.raises(struct.error):
        encode(msg)
    state = msgs.hlc_state_t()
    state.state = 300  # int8_t
    with pytest.raises(struct.error):
        encode(state)


def _fields(msg: Any) -> dict[str, Any]:
    """Every field of a decoded message, the header's included, with its type (bool stays bool)."""
    out = {name: (type(getattr(msg, name)), getattr(msg, name)) for name in msg.__slots__ if name != "header"}
    h = msg.header
    out.update({f"header.{n}": (type(getattr(h, n)), getattr(h, n)) for n in h.__slots__})
    return out


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
def test_fast_decoding_gives_lcm_gens_fields(cls: Any) -> None:
    if "header" not in cls.__slots__:
        assert decoder(cls) is cls.decode
        return
    r = random.Random("decode " + cls.__name__)
    for _ in range(50):
        msg = cls()
        _fill(msg, r)
        data = msg.encode()
        assert _fields(decoder(cls)(data)) == _fields(cls.decode(data))
        assert _fields(decoder(cls)(data + b"trailing")) == _fields(cls.decode(data + b"trailing"))


def _same_outcome(cls: Any, bad: bytes) -> None:
    try:
        expected: Any = _fields(cls.decode(bad))
    except Exception as exc:  # noqa: BLE001 - its type is what is compared
        expected = type(exc)
    try:
        got: Any = _fields(decoder(cls)(bad))
    except Exception as exc:  # noqa: BLE001
        got = type(exc)
    assert repr(got) == repr(expected), (cls.__name__, len(bad), bad)  # repr: NaN equals NaN


@pytest.mark.parametrize("mac", [b"", b"\x01\x02\x03\x04"], ids=["unsigned", "signed"])
@pytest.mark.parametrize("cls", [c for c in TYPES if c is not msgs.header_t], ids=lambda c: c.__name__)
def test_a_damaged_message_fails_or_decodes_as_lcm_gens(cls: Any, mac: bytes) -> None:
    """Every truncation, a wrong fingerprint, a negative or oversized MAC length, and every 2-byte
    and 4-byte field overwritten with hostile values (negative and huge array counts and string
    lengths): the same exception type as lcm-gen's decode, or the same fields where lcm-gen's
    reads what is there. Unsigned (no MAC: the decoder reads the header's end and the fields after
    it at once) and signed."""
    assert decoder(cls) is not cls.decode
    r = random.Random("damaged " + cls.__name__)
    msg = cls()
    _fill(msg, r)
    msg.header.agent, msg.header.mac_len, msg.header.mac = "b-001", len(mac), mac
    data = msg.encode()
    at = 8 + 8 + 4 + len("b-001") + 1 + 4  # the header's mac_len
    damaged = [data[:n] for n in range(len(data))]
    damaged += [b"\0" * 8 + data[8:], data[:at] + struct.pack(">h", -3) + data[at + 2 :]]
    damaged += [data[:at] + struct.pack(">h", 30_000) + data[at + 2 :]]
    damaged += [data[:at] + struct.pack(">h", n) + data[at + 2 :] for n in (0, 1, 4)]
    for offset in range(at - 4, len(data) - 1):
        for value in (b"\xff\xff", b"\x80\x00", b"\x7f\xff", b"\x00\x00", b"\x00\x05"):
            damaged.append(data[:offset] + value + data[offset + 2 :])
        for value in (b"\xff\xff\xff\xff", b"\x00\x00\x00\x00", b"\x00\x00\x00\x03"):
            damaged.append(data[:offset] + value + data[offset + 4 :])
    damaged += [bytes(r.randint(0, 255) for _ in range(len(data))) for _ in range(50)]
    damaged += [data[:8] + bytes(r.randint(0, 255) for _ in range(len(data) - 8)) for _ in range(200)]
    for bad in damaged:
        _same_outcome(cls, bad)
