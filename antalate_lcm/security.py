"""Command authentication (DESIGN §10): HMAC-SHA256 with a swarm key and a replay window.

The MAC covers the encoded message with ``mac`` empty, so any LCM implementation can verify it.
"""

from __future__ import annotations

import hashlib
import hmac
import time
from typing import Any, Protocol


class SignedMsg(Protocol):
    header: Any
    mac_len: int
    mac: bytes | list[int]

    def encode(self) -> bytes: ...


def _unsigned_bytes(msg: SignedMsg) -> bytes:
    saved_len, saved_mac = msg.mac_len, msg.mac
    msg.mac_len, msg.mac = 0, b""
    try:
        return msg.encode()
    finally:
        msg.mac_len, msg.mac = saved_len, saved_mac


def sign(msg: SignedMsg, key: str) -> None:
    """Fill ``mac`` in place; call after the header (utime, seq) is final."""
    digest = hmac.new(key.encode(), _unsigned_bytes(msg), hashlib.sha256).digest()
    msg.mac_len, msg.mac = len(digest), digest


def verify(msg: SignedMsg, key: str, window: float, *, now: float | None = None) -> str | None:
    """Return None if authentic and fresh, else the reason to reject (for the log)."""
    if msg.mac_len == 0:
        return "unsigned command while a swarm key is configured"
    expected = hmac.new(key.encode(), _unsigned_bytes(msg), hashlib.sha256).digest()
    if not hmac.compare_digest(expected, bytes(msg.mac)):
        return "bad MAC (forged, or signed with another key)"
    age = (time.time() if now is None else now) - msg.header.utime / 1e6
    if abs(age) > window:
        return f"outside the {window:g} s replay window (age {age:+.1f} s)"
    return None
