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
    """Random header and fields; a type with arrays keeps its defaults beyond the header (its
    counts and arrays must agree, and it is encoded by lcm-gen anyway)."""
    flat = all(d is None for d in msg.__dimensions__)
    for name, typename in zip(msg.__slots__, msg.__typenames__, strict=True):
        if name == "header":
            h = msg.header
            h.utime, h.seq = r.randint(0, 2**62), r.randint(0, 2**31 - 1)
            h.agent = r.choice(["", "b-001", "agent ünïcode"])
            h.mac_len = r.choice([0, 32])
            h.mac = bytes(r.randint(0, 255) for _ in range(h.mac_len))
        elif flat and typename in _VALUES:
            setattr(msg, name, _VALUES[typename](r))


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
def test_fast_encoding_is_lcm_gens_byte_for_byte(cls: type) -> None:
    r = random.Random(cls.__name__)
    for _ in range(50):
        msg = cls()
        _fill(msg, r)
        assert encode(msg) == msg.encode()
        assert type(msg).decode(encode(msg)).encode() == msg.encode()


def test_flat_types_are_compiled_and_the_rest_keep_lcm_gen() -> None:
    """A type with arrays or nested types other than the header (or no header: header_t itself)
    keeps its own encode; every flat one the node publishes per tick gets the fast one."""
    for flat in (msgs.telemetry_t, msgs.hlc_state_t, msgs.mc_state_t, msgs.velocity_cmd_t):
        assert encoder(flat) is not flat.encode
    for kept in (msgs.header_t, msgs.payload_t, msgs.peer_scan_t):
        assert encoder(kept) is kept.encode


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


@pytest.mark.parametrize("cls", [msgs.telemetry_t, msgs.mc_state_t, msgs.hlc_state_t, msgs.operator_cmd_t])
def test_a_damaged_message_fails_or_decodes_as_lcm_gens(cls: Any) -> None:
    """Every truncation, a wrong fingerprint and a negative or oversized MAC length: the same
    exception type as lcm-gen's decode, or the same fields where lcm-gen's reads what is there."""
    assert decoder(cls) is not cls.decode
    msg = cls()
    msg.header.agent, msg.header.mac_len, msg.header.mac = "b-001", 4, b"\x01\x02\x03\x04"
    data = msg.encode()
    at = 8 + 8 + 4 + len("b-001") + 1 + 4  # the header's mac_len
    damaged = [data[:n] for n in range(len(data))]
    damaged += [b"\0" * 8 + data[8:], data[:at] + struct.pack(">h", -3) + data[at + 2 :]]
    damaged += [data[:at] + struct.pack(">h", 30_000) + data[at + 2 :]]
    for bad in damaged:
        try:
            expected: Any = _fields(cls.decode(bad))
        except Exception as exc:  # noqa: BLE001 - its type is what is compared
            expected = type(exc)
        try:
            got: Any = _fields(decoder(cls)(bad))
        except Exception as exc:  # noqa: BLE001
            got = type(exc)
        assert got == expected, (len(bad), bad)
