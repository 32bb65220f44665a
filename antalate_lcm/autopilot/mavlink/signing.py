"""MAVLink 2 message signing: the 32-byte secret key from the configured text, as MAVProxy derives it.

With a key, every message the adapter sends carries a signature (SHA-256 over the key and the frame,
with a timestamp against replay) and every unsigned or badly signed message from the link is dropped:
on a shared radio network nobody without the key can command the copter or feed the HLC a forged
position. The vehicle needs the same key (docs/ardupilot.md: MAVProxy ``signing setup``).
"""

from __future__ import annotations

import hashlib
import re

from pymavlink.dialects.v20 import ardupilotmega as mav

_HEX_KEY = re.compile(r"[0-9a-fA-F]{64}")

#: Messages accepted unsigned even with signing on: SiK radios inject their own unsigned RADIO_STATUS
#: into the stream (ArduPilot accepts it unsigned for the same reason). The adapter does not use it.
UNSIGNED_OK = frozenset({mav.MAVLINK_MSG_ID_RADIO_STATUS})


def signing_key(text: str) -> bytes:
    """64 hex digits are the key itself; anything else is a passphrase, hashed with SHA-256 (MAVProxy)."""
    text = text.strip()
    if not text:
        raise ValueError("empty signing key")
    if _HEX_KEY.fullmatch(text):
        return bytes.fromhex(text)
    return hashlib.sha256(text.encode("utf-8")).digest()


def allow_unsigned(_mav: object, msg_id: int) -> bool:
    """pymavlink's ``allow_unsigned_callback``: only `UNSIGNED_OK` passes unsigned."""
    return msg_id in UNSIGNED_OK
