"""Message authentication (docs/design.md §10): HMAC-SHA256 with a swarm key and a replay window.

The MAC lives in ``header.mac`` of every message and covers the whole encoded message with the MAC
empty, so any LCM implementation (C, Java, Go) can sign and verify it with a plain HMAC.
"""

from __future__ import annotations

import hashlib
import hmac
import time
from typing import Any, Protocol


class SignedMsg(Protocol):
    """Any antalate message: every one starts with a ``header_t`` that carries ``mac_len``/``mac``."""

    header: Any

    def encode(self) -> bytes: ...


def _unsigned_bytes(msg: SignedMsg) -> bytes:
    header = msg.header
    saved_len, saved_mac = header.mac_len, header.mac
    header.mac_len, header.mac = 0, b""
    try:
        return msg.encode()
    finally:
        header.mac_len, header.mac = saved_len, saved_mac


def sign(msg: SignedMsg, key: str) -> None:
    """Fill ``mac`` in place; call after the header (utime, seq) is final."""
    digest = hmac.new(key.encode(), _unsigned_bytes(msg), hashlib.sha256).digest()
    msg.header.mac_len, msg.header.mac = len(digest), digest


def verify(msg: SignedMsg, key: str, window: float, *, now: float | None = None) -> str | None:
    """Return None if authentic and fresh, else the reason to reject (for the log)."""
    if msg.header.mac_len == 0:
        return "unsigned message while a swarm key is configured"
    expected = hmac.new(key.encode(), _unsigned_bytes(msg), hashlib.sha256).digest()
    if not hmac.compare_digest(expected, bytes(msg.header.mac)):
        return "bad MAC (forged, or signed with another key)"
    age = (time.time() if now is None else now) - msg.header.utime / 1e6
    if abs(age) > window:
        return f"outside the {window:g} s replay window (age {age:+.1f} s)"
    return None
