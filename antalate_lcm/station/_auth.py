"""The station's secrets, all kept as hashes or derived keys (pure: no I/O, no clock of its own).

* **API keys** (operators, scripts): random strings shown once; the station keeps SHA-256 of each
  with a name and a role. A key has 256 bits of entropy, so a fast hash is enough (no salt or
  slow KDF is needed against guessing: there is nothing to guess).
* **Agent tokens**: issued at registration, shown once in that reply; the database holds SHA-256.
* **The registration key**: HMAC-SHA256(swarm key, ``REGISTRATION_LABEL``). An agent proves it
  holds the swarm key by a MAC with it over its registration; the station can check that proof but
  cannot sign LCM commands (it never holds the swarm key itself).
"""

from __future__ import annotations

import hashlib
import hmac
import math
import secrets
from dataclasses import dataclass
from typing import Literal

Role = Literal["read-only", "operator"]
ROLES: tuple[Role, ...] = ("read-only", "operator")
REGISTRATION_LABEL = b"antalate station registration v1"
API_KEY_PREFIX = "antk_"


def sha256_hex(secret: str) -> str:
    return hashlib.sha256(secret.encode("utf-8")).hexdigest()


def new_api_key() -> str:
    """A fresh API key: a prefix (so it is recognisable in a leaked file) and 256 random bits."""
    return API_KEY_PREFIX + secrets.token_urlsafe(32)


def new_token() -> str:
    """A fresh agent token (192 random bits)."""
    return secrets.token_urlsafe(24)


def registration_key(swarm_key: str) -> str:
    """The station's registration key (hex) derived from the swarm key: what ``[station]
    registration_key`` holds. One-way: it gives no way back to the swarm key."""
    return hmac.new(swarm_key.encode("utf-8"), REGISTRATION_LABEL, hashlib.sha256).hexdigest()


def registration_message(name: str, utime: int, nonce: str) -> bytes:
    """What a registration proof covers: the name claimed, when, and a nonce (never reused).

    JSON has no canonical form, so the proof covers these fields, not the body's bytes; they are
    all a registration decides (the rest of the first report is an ordinary report).
    """
    return b"antalate-register\n%s\n%d\n%s" % (name.encode("utf-8"), utime, nonce.encode("utf-8"))


def registration_mac(reg_key_hex: str, name: str, utime: int, nonce: str) -> str:
    return hmac.new(
        bytes.fromhex(reg_key_hex), registration_message(name, utime, nonce), hashlib.sha256
    ).hexdigest()


def check_registration(
    reg_key_hex: str, name: str, utime: int, nonce: str, mac: str, now: float, window_s: float
) -> str | None:
    """None when the proof is valid and fresh, else the reason (for the 401 and the log)."""
    expected = registration_mac(reg_key_hex, name, utime, nonce)
    if not hmac.compare_digest(expected, mac.lower()):
        return "registration proof does not match (no swarm key, or another swarm's key)"
    age = now - utime / 1e6
    if abs(age) > window_s:
        return f"registration proof outside the {window_s:g} s window (age {age:+.1f} s: check the clocks)"
    return None


@dataclass(frozen=True, slots=True)
class Operator:
    """Who an API key belongs to."""

    name: str
    role: Role

    def may(self, role: Role) -> bool:
        return ROLES.index(self.role) >= ROLES.index(role)


def retry_after_header(seconds: float) -> str:
    """Retry-After is whole seconds; never 0 for a refusal."""
    return str(max(1, math.ceil(seconds)))
