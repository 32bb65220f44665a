"""Message authentication (docs/design.md §10, docs/security.md): HMAC-SHA256 with a swarm key, a
replay window and a per-sender replay guard whose memory of operator inputs survives restarts.

The MAC lives in ``header.mac`` of every message and covers the whole encoded message with the MAC
empty, so any LCM implementation (C, Java, Go) can sign and verify it with a plain HMAC.

Pure apart from :class:`HighWaterStore` (one small JSON file): :class:`Authenticator` is what a node
runs on every message it consumes; it is single-threaded by design (the node calls it on its
executor thread).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import hmac
import json
import logging
import os
import secrets
import struct
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from antalate_lcm.transports import transport_for
from antalate_lcm.wire.fastcodec import encode as fast_encode
from antalate_lcm.wire.topics import Message  # every antalate message starts with header_t (mac_len, mac)

log = logging.getLogger("antalate.security")


def _unsigned_bytes(msg: Message) -> bytes:
    header = msg.header
    saved_len, saved_mac = header.mac_len, header.mac
    header.mac_len, header.mac = 0, b""
    try:
        return fast_encode(msg)
    finally:
        header.mac_len, header.mac = saved_len, saved_mac


@functools.lru_cache(maxsize=16)
def _keyed(key: str) -> hmac.HMAC:
    """The HMAC state after the key (its two padded blocks): copied per message, not recomputed."""
    return hmac.new(key.encode(), digestmod=hashlib.sha256)


def _digest(key: str, data: bytes) -> bytes:
    mac = _keyed(key).copy()
    mac.update(data)
    return mac.digest()


def sign(msg: Message, key: str) -> None:
    """Fill ``mac`` in place; call after the header (utime, seq) is final. :func:`signed_bytes`, its
    bytes left unused (for programs that send the message themselves: tests, other tools)."""
    signed_bytes(msg, key)


def signed_bytes(msg: Message, key: str) -> bytes:
    """Sign ``msg`` (as :func:`sign`) and return its encoding, encoding it once instead of twice.

    Every antalate message starts with its ``header_t``, whose ``mac_len``/``mac`` follow the
    fingerprint, ``utime``, ``agent`` and ``seq``: the signed encoding is the unsigned one with the
    empty MAC field replaced, so it is spliced rather than encoded again (what ``Node.publish`` does).
    """
    header = msg.header
    unsigned = _unsigned_bytes(msg)
    digest = _digest(key, unsigned)
    header.mac_len, header.mac = len(digest), digest
    at = 8 + 8 + 4 + len(header.agent.encode("utf-8")) + 1 + 4  # fingerprint, utime, agent, seq
    if unsigned[at : at + 2] != b"\x00\x00":  # not laid out as expected: encode the plain way
        return msg.encode()
    return b"".join((unsigned[:at], struct.pack(">h", len(digest)), digest, unsigned[at + 2 :]))


def generate_key() -> str:
    """A new random swarm key: 32 random bytes, URL-safe text (what ``antalate keygen`` prints)."""
    return secrets.token_urlsafe(32)


class Reason(Enum):
    """Why a message was dropped (the counters' keys)."""

    UNSIGNED = "unsigned"
    FORGED = "forged"
    STALE = "stale"
    REPLAYED = "replayed"
    WRONG_SENDER = "wrong sender"


@dataclass(frozen=True)
class Rejection:
    reason: Reason
    text: str

    def __str__(self) -> str:
        return self.text


def check_mac(msg: Message, keys: Iterable[str]) -> Rejection | None:
    """None if ``msg`` carries a valid MAC under one of ``keys`` (the current key first)."""
    if msg.header.mac_len == 0:
        return Rejection(Reason.UNSIGNED, "unsigned message while a swarm key is configured")
    data = _unsigned_bytes(msg)
    mac = bytes(msg.header.mac)
    for key in keys:
        if key and hmac.compare_digest(_digest(key, data), mac):
            return None
    return Rejection(Reason.FORGED, "bad MAC (forged, or signed with another key)")


def check_datagram(data: bytes, keys: Iterable[str], window: float, now: float) -> Rejection | None:
    """:func:`check_mac` and :func:`check_window` on an encoded message, without decoding it.

    For a reader that keeps only some of what it hears (the operator console takes the newest state
    per channel): the MAC field sits at a fixed place after the fingerprint, ``utime``, ``agent``
    and ``seq`` of the ``header_t`` every antalate message starts with, so the unsigned bytes are
    spliced out of the datagram rather than re-encoded. A datagram too short to hold a header is
    unsigned as far as this can tell.
    """
    try:
        (utime,) = struct.unpack_from(">q", data, 8)
        (agent_len,) = struct.unpack_from(">I", data, 16)
        at = 20 + agent_len + 4
        (mac_len,) = struct.unpack_from(">h", data, at)
    except struct.error:
        return Rejection(Reason.UNSIGNED, "too short to carry a header_t and its MAC")
    end = at + 2 + mac_len
    if mac_len <= 0 or end > len(data):
        return Rejection(Reason.UNSIGNED, "unsigned message while a swarm key is configured")
    mac = data[at + 2 : end]
    unsigned = b"".join((data[:at], b"\x00\x00", data[end:]))
    if not any(key and hmac.compare_digest(_digest(key, unsigned), mac) for key in keys):
        return Rejection(Reason.FORGED, "bad MAC (forged, or signed with another key)")
    age = now - utime / 1e6
    if abs(age) > window:
        return Rejection(Reason.STALE, f"outside the {window:g} s window (age {age:+.1f} s)")
    return None


def check_window(msg: Message, window: float, now: float) -> Rejection | None:
    """None if ``header.utime`` is within ``window`` s of ``now`` (wall clock, s)."""
    age = now - msg.header.utime / 1e6
    if abs(age) <= window:
        return None
    if age < 0:
        text = f"from the future: the sender's clock is {-age:.1f} s ahead of ours (window {window:g} s)"
    else:
        text = f"outside the {window:g} s replay window (age {age:+.1f} s: replayed, or clocks {age:.1f} s apart)"
    return Rejection(Reason.STALE, text)


def verify(
    msg: Message, key: str, window: float, *, now: float | None = None, previous_keys: Iterable[str] = ()
) -> str | None:
    """Return None if authentic and fresh, else the reason to reject (for the log).

    No replay guard here: see :class:`Authenticator` for what a node does with every message.
    """
    problem = check_mac(msg, (key, *previous_keys)) or check_window(
        msg, window, time.time() if now is None else now
    )
    return None if problem is None else problem.text


# ---------------------------------------------------------------------------------------------- replay
class HighWaterStore:
    """Per-sender high-water ``utime`` of accepted operator inputs, in one small JSON file.

    Written atomically (temporary file, fsync, rename) after every change, so a power cut leaves
    the old or the new file, never half of one. A missing file is an empty memory; an unreadable
    one is reported and replaced (the replay window still bounds what could be replayed then).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._marks: dict[str, int] = {}
        try:
            raw = json.loads(self.path.read_text(encoding="utf-8"))
            if not isinstance(raw, dict):
                raise ValueError("not a JSON object")
            self._marks = {str(k): int(v) for k, v in raw.items()}
        except FileNotFoundError:
            pass
        except (OSError, ValueError, TypeError) as exc:
            log.warning("replay memory %s is unreadable (%s): starting empty", self.path, exc)

    def load(self) -> dict[str, int]:
        return dict(self._marks)

    def save(self, marks: dict[str, int]) -> None:
        self._marks = dict(marks)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=self.path.name + ".", suffix=".tmp", dir=self.path.parent)
            try:
                with os.fdopen(fd, "w", encoding="utf-8") as f:
                    json.dump(self._marks, f, sort_keys=True)
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, self.path)
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                raise
        except OSError as exc:
            log.warning("cannot write the replay memory %s: %s (kept in memory only)", self.path, exc)


class ReplayGuard:
    """Per (sender, message type) strictly increasing ``header.utime``.

    A resend by the console re-stamps ``utime`` (and keeps ``seq``), so it passes; the MC's seq
    logic makes it idempotent. The same decoded object handed to several subscriptions of one node
    (one datagram) is one delivery, not a replay: the last accepted object per key is remembered.
    Keys whose message type is in ``persisted`` are written to ``store`` on every acceptance.
    """

    def __init__(self, store: HighWaterStore | None = None, persisted: Iterable[str] = ()) -> None:
        self._store = store
        self._persisted = frozenset(persisted)
        self._marks: dict[str, int] = store.load() if store is not None else {}
        self._last: dict[str, Any] = {}

    @staticmethod
    def key(sender: str, type_name: str) -> str:
        return f"{type_name}/{sender}"

    def check(self, msg: Any, sender: str, type_name: str) -> Rejection | None:
        key = self.key(sender, type_name)
        mark = self._marks.get(key)
        utime = int(msg.header.utime)
        if mark is not None and utime <= mark:
            if self._last.get(key) is msg:
                return None
            return Rejection(
                Reason.REPLAYED,
                f"replayed or out of order: utime {utime} is not after the last accepted {mark} "
                f"({(mark - utime) / 1e6:.3f} s earlier)",
            )
        self._marks[key] = utime
        self._last[key] = msg
        if self._store is not None and type_name in self._persisted:
            self._store.save({k: v for k, v in self._marks.items() if k.split("/", 1)[0] in self._persisted})
        return None


# ---------------------------------------------------------------------------------------------- policy
@dataclass(frozen=True)
class SecurityPolicy:
    """The ``[security]`` settings a node needs, in one value (keys first: the current one signs)."""

    key: str = ""
    previous_keys: tuple[str, ...] = ()
    window: float = 5.0

    @property
    def enabled(self) -> bool:
        return bool(self.key)

    @property
    def keys(self) -> tuple[str, ...]:
        return (self.key, *self.previous_keys)


class Authenticator:
    """What a node runs on every message it consumes: MAC, window, sender binding, replay guard.

    Rejections are counted by reason and logged once per (reason, channel) per ``log_period``.
    """

    def __init__(
        self,
        policy: SecurityPolicy,
        logger: logging.Logger,
        *,
        replay_guard: ReplayGuard | None = None,
        wallclock: Callable[[], float] = time.time,
        log_period: float = 10.0,
    ) -> None:
        from antalate_lcm.base.ratelimit import RateLimitedLog

        self.policy = policy
        self.replay_guard = replay_guard or ReplayGuard()
        self._wallclock = wallclock
        self._log = RateLimitedLog(logger, period=log_period)
        self.rejected: dict[Reason, int] = {}
        self.accepted = 0

    def check(self, msg: Any, channel: str, *, expected_sender: str | None = None) -> Rejection | None:
        """None to deliver ``msg``; else the rejection (already counted and logged)."""
        problem = check_mac(msg, self.policy.keys)
        if problem is None:
            problem = check_window(msg, self.policy.window, self._wallclock())
        sender = str(msg.header.agent)
        if problem is None and expected_sender is not None and sender != expected_sender:
            problem = Rejection(
                Reason.WRONG_SENDER,
                f"signed by {sender!r} but {channel} carries only {expected_sender!r}'s messages",
            )
        if problem is None:
            problem = self.replay_guard.check(msg, sender, type(msg).__name__)
        if problem is None:
            self.accepted += 1
            return None
        n = self.rejected.get(problem.reason, 0) + 1
        self.rejected[problem.reason] = n
        self._log.log(
            (problem.reason, channel),
            logging.WARNING,
            "dropped %s on %s from %r seq %d: %s (%d %s so far)",
            type(msg).__name__,
            channel,
            sender,
            msg.header.seq,
            problem.text,
            n,
            problem.reason.value,
        )
        return problem


MEMBER_LABEL = b"antalate group member v1"


@dataclass(frozen=True)
class MemberProof:
    """Liveliness-token names that prove "member M of group G was alive at time T" with the swarm key.

    A bridge election counts the tokens under a group key (docs/wan.md); anyone who reaches the
    router can declare a token there, so each one is named ``MEMBER.MS.MAC`` (MS: wall-clock
    milliseconds, MAC: HMAC-SHA256 of the swarm key over group, member and time, 128 bits) and is
    re-declared every ``refresh`` seconds. A token is believed while its time is within ``window``
    (+ ``refresh``) of the reader's clock: a copied token keeps a member alive that long at most.
    """

    keys: tuple[str, ...]
    window: float = 5.0
    refresh: float = 1.0

    @staticmethod
    def _mac(key: str, group: str, member: str, ms: int) -> str:
        text = b"%s\n%s\n%s\n%d" % (MEMBER_LABEL, group.encode(), member.encode(), ms)
        return hmac.new(key.encode(), text, hashlib.sha256).hexdigest()[:32]

    def token(self, group: str, member: str, now: float) -> str:
        ms = int(now * 1000)
        return f"{member}.{ms}.{self._mac(self.keys[0], group, member, ms)}"

    def check(self, group: str, name: str, now: float) -> tuple[str, float] | str:
        """(member, time) of a valid, fresh token name, else why it is not believed."""
        member, _, rest = name.partition(".")
        ms_text, _, mac = rest.partition(".")
        if not member or not ms_text.isdigit() or len(mac) != 32:
            return "not a signed member token"
        ms = int(ms_text)
        if not any(hmac.compare_digest(self._mac(k, group, member, ms), mac) for k in self.keys):
            return "its MAC does not match the swarm key"
        age = now - ms / 1000
        if abs(age) > self.window + self.refresh:
            return f"stale (age {age:+.1f} s, window {self.window:g} s)"
        return member, ms / 1000

    def fresh(self, t: float, now: float) -> bool:
        return now - t <= self.window + self.refresh


def network_reachable(url: str) -> bool:
    """Whether a bus URL can carry datagrams from other hosts (its transport says: all but memq://
    and file://). A URL no transport serves is an error, never a guess either way."""
    return transport_for(url).network_reachable


def default_state_dir() -> Path:
    """``$XDG_STATE_HOME/antalate`` (``~/.local/state/antalate`` when unset)."""
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(base) / "antalate"


__all__ = [
    "Authenticator",
    "HighWaterStore",
    "Reason",
    "Rejection",
    "ReplayGuard",
    "SecurityPolicy",
    "check_mac",
    "check_window",
    "default_state_dir",
    "generate_key",
    "network_reachable",
    "sign",
    "signed_bytes",
    "verify",
]
