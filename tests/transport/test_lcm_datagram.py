"""LCM's udpm wire format read without liblcm (antalate_lcm/transports/datagram.py): every hostile datagram
is dropped and counted, never raised, and partial messages stay bounded."""

from __future__ import annotations

import random
import struct

import pytest

from antalate_lcm.transports.datagram import (
    MAGIC_LONG,
    MAX_MESSAGE_SIZE,
    Reassembler,
    fragments,
    short_datagram,
)

SENDER = ("10.0.0.1", 40000)


def _fragment(seqno: int, size: int, offset: int, number: int, count: int, body: bytes) -> bytes:
    return struct.pack(">IIIIHH", MAGIC_LONG, seqno, size, offset, number, count) + body


def test_a_short_datagram_gives_its_channel_and_payload() -> None:
    r = Reassembler()
    assert r.feed(short_datagram("uav1/TELEMETRY", b"\x00\x01payload", seqno=7), SENDER) == (
        "uav1/TELEMETRY",
        b"\x00\x01payload",
    )
    assert r.feed(short_datagram("EMPTY", b""), SENDER) == ("EMPTY", b"")
    assert r.dropped == 0


def test_channel_names_follow_liblcms_limit() -> None:
    r = Reassembler()
    assert r.feed(short_datagram("c" * 63, b"x"), SENDER) == ("c" * 63, b"x")
    assert r.feed(short_datagram("c" * 64, b"x"), SENDER) is None  # liblcm: over 63 bytes
    assert r.feed(struct.pack(">II", 0x4C433032, 0) + b"no-terminator", SENDER) is None
    assert r.feed(struct.pack(">II", 0x4C433032, 0) + b"\xff\xfe\0data", SENDER) is None  # not UTF-8
    assert r.dropped == 3


@pytest.mark.parametrize("length", range(20))
def test_truncated_and_unknown_datagrams_are_counted_not_raised(length: int) -> None:
    r = Reassembler()
    for data in (
        short_datagram("A", b"x")[:length],
        fragments("A", b"y" * 10)[0][:length],
        b"\xff" * length,
    ):
        assert r.feed(data, SENDER) is None or length > 9
    assert r.dropped >= 1


@pytest.mark.parametrize("order", ["in order", "reversed", "shuffled", "duplicated"])
def test_fragments_are_reassembled_in_any_order(order: str) -> None:
    payload = bytes(random.Random(1).randrange(256) for _ in range(10_000))
    frags = fragments("BIG", payload, seqno=3, size=1000)
    assert len(frags) == 11
    if order == "reversed":
        frags.reverse()
    elif order == "shuffled":
        random.Random(2).shuffle(frags)
    elif order == "duplicated":
        frags = [f for f in frags for _ in range(2)]
    r = Reassembler()
    out = [m for m in (r.feed(f, SENDER) for f in frags) if m is not None]
    assert out == [("BIG", payload)]  # once: a duplicate is not a missing fragment found
    # (a duplicate of the last fragment, after the message is out, opens a partial as in liblcm)
    assert r.pending == (1 if order == "duplicated" else 0) and r.dropped == 0


def test_a_fragment_past_its_message_drops_the_partial() -> None:
    r = Reassembler()
    good = fragments("BIG", b"z" * 3000, seqno=1, size=1000)
    assert r.feed(good[0], SENDER) is None and r.pending == 1
    assert r.feed(_fragment(1, 3000, 2900, 1, 4, b"w" * 200), SENDER) is None
    assert r.pending == 0 and r.dropped == 1
    assert all(r.feed(f, SENDER) is None for f in good[1:])  # the rest can no longer complete it


def test_impossible_headers_are_refused() -> None:
    r = Reassembler()
    assert r.feed(_fragment(1, MAX_MESSAGE_SIZE + 1, 0, 0, 2, b"C\0data"), SENDER) is None
    assert r.feed(_fragment(2, 100, 0, 0, 0, b"C\0data"), SENDER) is None  # zero fragments
    assert r.feed(_fragment(3, 100, 0, 0, 2, b"no terminator"), SENDER) is None
    assert r.dropped == 3 and r.pending == 0


def test_a_reused_sequence_number_with_another_size_starts_afresh() -> None:
    r = Reassembler()
    old = fragments("A", b"o" * 3000, seqno=9, size=1000)
    new = fragments("A", b"n" * 2500, seqno=9, size=1000)
    assert r.feed(old[0], SENDER) is None
    out = [m for m in (r.feed(f, SENDER) for f in new) if m is not None]
    assert out == [("A", b"n" * 2500)]
    assert r.pending == 0


def test_two_senders_with_one_sequence_number_do_not_mix() -> None:
    r = Reassembler()
    a = fragments("A", b"a" * 2000, seqno=5, size=1000)
    b = fragments("B", b"b" * 2000, seqno=5, size=1000)
    assert len(a) == len(b) == 3
    out = []
    for fa, fb in zip(a, b, strict=True):
        out += [r.feed(fa, ("10.0.0.1", 1)), r.feed(fb, ("10.0.0.2", 1))]
    assert [m for m in out if m is not None] == [("A", b"a" * 2000), ("B", b"b" * 2000)]


def test_partial_messages_are_bounded_in_count_and_bytes() -> None:
    r = Reassembler(max_partial=10, max_partial_bytes=50_000)
    for seqno in range(100):  # a flood of first fragments that never complete
        assert r.feed(fragments("F", b"f" * 4000, seqno=seqno, size=1000)[0], SENDER) is None
        assert r.pending <= 10
    assert r.evicted == 90
    r2 = Reassembler(max_partial=1000, max_partial_bytes=20_000)
    for seqno in range(20):
        r2.feed(fragments("F", b"f" * 4000, seqno=seqno, size=1000)[0], SENDER)
    assert r2.pending == 5  # 5 x 4,000 bytes fit in 20,000
    assert r2.feed(_fragment(99, 30_000, 0, 0, 30, b"F\0" + b"x" * 100), SENDER) is None
    assert r2.dropped == 1  # could never fit: refused rather than evicting everything for it
    # the newest partial survives the flood and still completes
    last = fragments("F", b"f" * 4000, seqno=19, size=1000)
    done = [m for m in (r2.feed(f, SENDER) for f in last[1:]) if m is not None]
    assert done == [("F", b"f" * 4000)]


def test_every_fragment_counted_but_fragment_zero_never_came() -> None:
    r = Reassembler()
    assert r.feed(_fragment(4, 20, 0, 1, 2, b"x" * 10), SENDER) is None
    assert r.feed(_fragment(4, 20, 10, 2, 2, b"y" * 10), SENDER) is None  # forged numbering
    assert r.pending == 0 and r.dropped == 1


def test_random_bytes_never_raise() -> None:
    rng = random.Random(15)
    r = Reassembler(max_partial=50, max_partial_bytes=1 << 20)
    heads = [struct.pack(">I", 0x4C433032), struct.pack(">I", MAGIC_LONG), b""]
    for _ in range(20_000):
        body = bytes(rng.randrange(256) for _ in range(rng.randrange(40)))
        r.feed(rng.choice(heads) + body, (str(rng.randrange(3)), 1))
    assert r.pending <= 50
