"""LCM's UDP multicast wire format, read without liblcm: short datagrams and reassembled fragments.

Pure (no sockets), so every hostile datagram is a unit test. It follows liblcm 1.5's
``lcm_udpm.c``/``udpm_util.h`` byte for byte, so a message sent by any LCM implementation (the
stock tools included) arrives exactly as liblcm would deliver it:

- **short** (``LC02``): magic ``0x4c433032``, u32 sequence number, the channel NUL-terminated, then
  the payload -- one datagram.
- **fragment** (``LC03``): magic ``0x4c433033``, u32 sequence number, u32 message size, u32 offset,
  u16 fragment number, u16 fragment count; fragment 0 carries the NUL-terminated channel before its
  data. Fragments are kept per (sender, sequence number); a message is delivered when its last
  missing fragment arrives, in any order.

What liblcm drops is dropped here too, and counted: an unknown magic, a channel over 63 bytes or
without its NUL, a message over 256 MiB, a fragment that would write past its message. Partial
messages are bounded the way liblcm bounds them (1,000 at most, 16 MiB in all; the least recently
updated goes first), so a flood of first fragments that never complete costs bounded memory.

Two things liblcm does not do, both against amplification (issue 29): a message is delivered only
when its fragments carried all of its bytes (liblcm delivers a 47-byte datagram that claims 16 MiB in
"one fragment" as 16 MiB of zeros), and a reader may set a smaller size limit, per channel too, that
is checked on the first fragment that names the size -- before any buffer is allocated.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

MAGIC_SHORT = 0x4C433032  # "LC02"
MAGIC_LONG = 0x4C433033  # "LC03"
#: liblcm's limits (lcm.h, udpm_util.h).
MAX_CHANNEL_LENGTH = 63
MAX_MESSAGE_SIZE = 1 << 28
MAX_PARTIAL_MESSAGES = 1000
MAX_PARTIAL_BYTES = 1 << 24

_SHORT = struct.Struct(">II")
_LONG = struct.Struct(">IIIIHH")
SHORT_MAGIC_BYTES = _SHORT.pack(MAGIC_SHORT, 0)[:4]


def short_datagram(channel: str, payload: bytes, seqno: int = 0) -> bytes:
    """One ``LC02`` datagram, as liblcm sends a message that fits (for tests and tools)."""
    return _SHORT.pack(MAGIC_SHORT, seqno) + channel.encode() + b"\0" + payload


def fragments(channel: str, payload: bytes, seqno: int = 0, size: int = 65_000) -> list[bytes]:
    """``LC03`` datagrams of at most ``size`` bytes of data each, as liblcm splits a large message."""
    name = channel.encode() + b"\0"
    chunks: list[tuple[int, bytes]] = []
    offset = 0
    first = max(size - len(name), 1)
    while offset < len(payload) or not chunks:
        take = first if not chunks else size
        chunks.append((offset, payload[offset : offset + take]))
        offset += take
    out = []
    for n, (off, chunk) in enumerate(chunks):
        head = _LONG.pack(MAGIC_LONG, seqno, len(payload), off, n, len(chunks))
        out.append(head + (name if n == 0 else b"") + chunk)
    return out


def channel_problem(channel: str) -> str | None:
    """Why liblcm cannot send on ``channel`` (it raises ValueError deep in publish), or None."""
    if not channel:
        return "an empty channel name"
    if "\0" in channel:
        return "a NUL byte in the channel name"
    if len(channel.encode()) > MAX_CHANNEL_LENGTH:
        return f"a channel name over {MAX_CHANNEL_LENGTH} bytes"
    return None


@dataclass
class _Partial:
    size: int
    remaining: int
    data: bytearray
    channel: str | None = None
    seen: set[int] = field(default_factory=set)
    #: Bytes the fragments carried (a duplicate counted once): all of ``size`` or nothing is delivered.
    got: int = 0


class Reassembler:
    """Turns datagrams into ``(channel, payload)`` messages; one per receiving socket.

    ``dropped`` counts datagrams that were not LCM or were damaged (liblcm's ``udp_discarded_bad``
    plus the fragments it drops), ``evicted`` the partial messages pushed out by the bounds,
    ``oversize`` the fragments of messages over ``max_message_size`` (or over ``size_limit`` of
    their channel), dropped before anything was allocated for them.
    """

    def __init__(
        self,
        max_partial: int = MAX_PARTIAL_MESSAGES,
        max_partial_bytes: int = MAX_PARTIAL_BYTES,
        *,
        max_message_size: int = MAX_MESSAGE_SIZE,
        size_limit: Callable[[str], int] | None = None,
    ) -> None:
        self._partial: dict[tuple[Hashable, int], _Partial] = {}
        self._partial_bytes = 0
        self._max_partial = max_partial
        self._max_partial_bytes = max_partial_bytes
        self._max_message = min(max_message_size, MAX_MESSAGE_SIZE)
        self._size_limit = size_limit
        self.dropped = 0
        self.evicted = 0
        self.oversize = 0

    def short(self, datagram: bytes) -> tuple[str, bytes] | None:
        """A short (``LC02``) datagram's channel and payload, or None when it is damaged."""
        end = datagram.find(b"\0", 8, 8 + MAX_CHANNEL_LENGTH + 1)
        if end < 0:
            self.dropped += 1
            return None
        try:
            channel = datagram[8:end].decode()
        except UnicodeDecodeError:
            self.dropped += 1
            return None
        return channel, datagram[end + 1 :]

    def feed(self, datagram: bytes, sender: Hashable) -> tuple[str, bytes] | None:
        """The message this datagram completes, if any; ``sender`` keys fragments (the source address)."""
        magic = datagram[:4]
        if magic == SHORT_MAGIC_BYTES and len(datagram) >= 8:
            return self.short(datagram)
        if len(datagram) >= _LONG.size and _LONG.unpack_from(datagram)[0] == MAGIC_LONG:
            return self._fragment(datagram, sender)
        self.dropped += 1
        return None

    def _fragment(self, datagram: bytes, sender: Hashable) -> tuple[str, bytes] | None:
        _, seqno, size, offset, number, count = _LONG.unpack_from(datagram)
        key = (sender, seqno)
        partial = self._partial.get(key)
        if partial is not None and partial.size != size:  # a stale message under a reused seqno
            self._forget(key)
            partial = None
        if size > MAX_MESSAGE_SIZE or count == 0:
            self.dropped += 1
            return None
        if size > self._max_message:
            self.oversize += 1
            if partial is not None:
                self._forget(key)
            return None
        start = _LONG.size
        channel = None
        if number == 0:
            end = datagram.find(b"\0", start, start + MAX_CHANNEL_LENGTH + 1)
            if end < 0:
                self.dropped += 1
                return None
            try:
                channel = datagram[start:end].decode()
            except UnicodeDecodeError:
                self.dropped += 1
                return None
            start = end + 1
            if self._size_limit is not None and size > self._size_limit(channel):
                self.oversize += 1
                if partial is not None:
                    self._forget(key)
                return None
        chunk = memoryview(datagram)[start:]
        if offset + len(chunk) > size:
            self.dropped += 1
            if partial is not None:
                self._forget(key)
            return None
        if partial is None:
            if size > self._max_partial_bytes:
                self.dropped += 1  # could never fit: liblcm would evict everything else for it
                return None
            self._make_room(size)
            partial = _Partial(size, count, bytearray(size))
            self._partial[key] = partial
            self._partial_bytes += size
        else:  # least recently updated goes first: move to the end
            del self._partial[key]
            self._partial[key] = partial
        if channel is not None:
            partial.channel = channel
        partial.data[offset : offset + len(chunk)] = chunk
        if number not in partial.seen:  # a duplicated fragment is not a missing one found
            partial.seen.add(number)
            partial.remaining -= 1
            partial.got += len(chunk)
        if partial.remaining > 0:
            return None
        self._forget(key)
        if partial.channel is None or partial.got < partial.size:
            # every fragment counted but fragment 0 never came, or the fragments did not carry the
            # size they claimed (forged count): never deliver bytes nobody sent
            self.dropped += 1
            return None
        return partial.channel, bytes(partial.data)

    def _make_room(self, size: int) -> None:
        partial = self._partial
        while partial and (
            len(partial) >= self._max_partial or self._partial_bytes + size > self._max_partial_bytes
        ):
            self._forget(next(iter(partial)))
            self.evicted += 1

    def _forget(self, key: tuple[Hashable, int]) -> None:
        gone = self._partial.pop(key, None)
        if gone is not None:
            self._partial_bytes -= gone.size

    @property
    def pending(self) -> int:
        """Partial messages waiting for fragments."""
        return len(self._partial)
