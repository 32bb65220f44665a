"""MAVLink 2 message signing: the 32-byte secret key from the configured text, as MAVProxy derives it.

With a key, every message the adapter sends carries a signature (SHA-256 over the key and the frame,
with a timestamp against replay) and every unsigned or badly signed message from the link is dropped:
on a shared radio network nobody without the key can command the copter or feed the HLC a forged
position. The vehicle needs the same key (docs/ardupilot.md: MAVProxy ``signing setup``).
"""

from __future__ import annotations

import hashlib
import re
import struct
from typing import Any

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


_TIMESTAMP = struct.Struct("<IH")  # 48-bit little-endian timestamp, 10 us units since 2015-01-01
_NEW_STREAM_SLACK = 6000 * 1000  # a new stream may start up to 60 s behind our clock (pymavlink's rule)


def verify_signature_first(mav_obj: Any) -> None:
    """Make `mav_obj` (a pymavlink ``MAVLink``) check the signature before it trusts the timestamp.

    pymavlink's ``check_signature`` records a frame's timestamp for its stream *before* comparing the
    signature. A frame signed with any key and a future timestamp, sent as the vehicle (same link id,
    system and component), then makes every genuine frame look like a replay: one forged datagram cuts
    the link (the HLC goes LLC_DOWN). Here the signature is checked first and only a genuine frame moves
    the stream's timestamp; the replay and new-stream rules are pymavlink's.
    """
    signing = mav_obj.signing

    def check_signature(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        key = signing.secret_key
        if key is None or len(msgbuf) < 13:
            return False
        digest = hashlib.sha256(bytes(key) + bytes(msgbuf[:-6])).digest()[:6]
        if digest != bytes(msgbuf[-6:]):
            return False
        low, high = _TIMESTAMP.unpack(bytes(msgbuf[-12:-6]))
        timestamp = low + (high << 32)
        stream = (msgbuf[-13], src_system, src_component)
        last = signing.stream_timestamps.get(stream)
        if last is not None and timestamp <= last:
            return False  # a replay (or a reordered frame)
        if last is None and timestamp + _NEW_STREAM_SLACK < signing.timestamp:
            return False  # a new stream from the past: a recording
        signing.stream_timestamps[stream] = timestamp
        signing.timestamp = max(signing.timestamp, timestamp)
        return True

    mav_obj.check_signature = check_signature
