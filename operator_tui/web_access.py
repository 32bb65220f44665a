"""Who may use ``antalate tui --web`` (:mod:`operator_tui.web`): operator API keys and the sessions they
open (:class:`ConsoleAccess`), the keys file re-read when it changes (:class:`KeysFile`), and the Host
and Origin checks that keep other web sites and DNS rebinding out (:func:`allowed_hosts`,
:func:`host_allowed`, :func:`same_origin`). Pure but for reading the keys file: the server asks these.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import os
import secrets
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from antalate_lcm.base.errors import AntalateError

if TYPE_CHECKING:
    from antalate_lcm.station import ApiKey

log = logging.getLogger("antalate.tui.web")

SESSION_TTL_S = 12 * 3600.0
#: The names a loopback console answers to (besides loopback addresses).
LOOPBACK_NAMES = ("localhost",)


@dataclass(frozen=True)
class Refusal:
    status: int
    text: str


@dataclass
class ConsoleAccess:
    """Operator API keys (as SHA-256) and the browser sessions they opened. Pure: the clock is passed.

    A session token is random and kept only in memory: restarting the server signs everyone out,
    which is what an operator expects of a console that was restarted.
    """

    keys: tuple[ApiKey, ...]
    ttl_s: float = SESSION_TTL_S
    #: token -> (holder's name, the SHA-256 of the key it signed in with, expiry)
    sessions: dict[str, tuple[str, str, float]] = field(default_factory=dict)

    def login(self, key: str, now: float) -> tuple[str, str] | Refusal:
        """A new session (token, holder's name) for a valid operator key, else why not."""
        from antalate_lcm.station import sha256_hex

        digest = sha256_hex(key.strip())
        match = next((k for k in self.keys if hmac.compare_digest(k.sha256, digest)), None)
        if match is None:
            return Refusal(401, "Unknown API key.")
        if match.role != "operator":
            return Refusal(
                403,
                f"The key of {match.name!r} is {match.role}: the console commands vehicles, "
                "it needs an operator key.",
            )
        self._expire(now)
        token = secrets.token_urlsafe(32)
        self.sessions[token] = (match.name, match.sha256, now + self.ttl_s)
        return token, match.name

    def holder(self, token: str | None, now: float) -> str | None:
        """The name behind a live session token, or None."""
        if not token:
            return None
        entry = self.sessions.get(token)
        if entry is None or entry[2] < now:
            self.sessions.pop(token, None)
            return None
        return entry[0]

    def replace_keys(self, keys: tuple[ApiKey, ...]) -> list[str]:
        """Take the keys file's new contents; end the sessions of keys no longer there as operator
        keys and return their tokens (their open consoles must be closed too)."""
        self.keys = keys
        valid = {k.sha256 for k in keys if k.role == "operator"}
        ended = [t for t, (_, digest, _) in self.sessions.items() if digest not in valid]
        for token in ended:
            del self.sessions[token]
        return ended

    def _expire(self, now: float) -> None:
        for token in [t for t, (_, _, until) in self.sessions.items() if until < now]:
            del self.sessions[token]


@dataclass
class KeysFile:
    """The keys file, re-read when its (mtime, size, inode) changes. A file that cannot be read or
    holds no operator key is taken as *no keys* (fail closed: every session ends) and said so."""

    path: str
    stamp: tuple[int, int, int] | None = None

    def _stamp(self) -> tuple[int, int, int] | None:
        try:
            st = os.stat(self.path)
        except OSError:
            return None
        return (st.st_mtime_ns, st.st_size, st.st_ino)

    def load(self) -> tuple[ApiKey, ...]:
        self.stamp = self._stamp()
        return load_keys(self.path)

    def changed(self) -> tuple[ApiKey, ...] | None:
        """The new keys if the file changed since the last look, else None."""
        stamp = self._stamp()
        if stamp == self.stamp:
            return None
        self.stamp = stamp
        try:
            return load_keys(self.path)
        except (AntalateError, OSError) as exc:
            log.error(
                "console keys file %s unusable, every session ended until it is fixed: %s", self.path, exc
            )
            return ()


def load_keys(path: str) -> tuple[ApiKey, ...]:
    """The ``[[api_keys]]`` of a station config (or of a file holding only those tables)."""
    from antalate_lcm.station import load_station_file

    keys = load_station_file(path).settings.api_keys
    if not any(k.role == "operator" for k in keys):
        raise AntalateError(f'{path} has no [[api_keys]] entry with role = "operator": nobody could sign in')
    return keys


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def allowed_hosts(listen: str, extra: Iterable[str] = ()) -> frozenset[str]:
    """The host names (lower case, IPv6 without brackets) a request's Host may carry by name.

    An IP literal is checked apart (:func:`host_allowed`): DNS rebinding needs a *name* the attacker
    controls, so a name is accepted only when listed: the listen address itself, ``localhost`` for a
    loopback server, and ``--allow-host``."""
    names = {listen.lower().strip("[]"), *(h.lower().strip("[]") for h in extra)}
    if is_loopback(listen):
        names.update(LOOPBACK_NAMES)
    return frozenset(names)


def _split_host(host_header: str) -> str:
    """The host part of a Host header (``[::1]:8000`` -> ``::1``, ``Name:80`` -> ``name``)."""
    h = host_header.strip().lower()
    if h.startswith("["):
        return h[1 : h.find("]")] if "]" in h else h
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def host_allowed(host_header: str | None, listen: str, names: frozenset[str]) -> bool:
    """Whether a request's Host names this server: a listed name, or an address it listens on (any
    address when it listens on all of them; only a loopback one when it listens on loopback)."""
    if not host_header:
        return False
    host = _split_host(host_header)
    if host in names:
        return True
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return False
    try:
        bound = ipaddress.ip_address(listen.strip("[]"))
    except ValueError:  # listening on a name: only the names given count
        return False
    if bound.is_unspecified:
        return True
    if bound.is_loopback:
        return address.is_loopback
    return address == bound


def same_origin(origin: str | None, scheme: str, host: str) -> bool:
    """Browsers send Origin with every WebSocket and form POST; a client without one cannot be a
    cross-site page. ``host`` is the request's Host, already checked by :func:`host_allowed`."""
    return origin is None or origin.lower() == f"{scheme}://{host}".lower()


__all__ = [
    "LOOPBACK_NAMES",
    "SESSION_TTL_S",
    "ConsoleAccess",
    "KeysFile",
    "Refusal",
    "allowed_hosts",
    "host_allowed",
    "is_loopback",
    "load_keys",
    "same_origin",
]
