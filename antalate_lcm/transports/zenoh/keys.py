"""Zenoh keys of LCM channels, pure: one key ``PREFIX/CHANNEL`` per channel (the characters Zenoh reserves
escaped as ``%XX``, an empty chunk as ``%-``), its inverse, and the channel regexes that are one literal
channel (subscribed to by their key, routed by Zenoh itself, not filtered here)."""

from __future__ import annotations

import re

_SPECIAL = ".^$*+?()[]{}|\\"
_LITERAL = re.compile(r"(?:[^.^$*+?()\[\]{}|\\]|\\[.^$*+?()\[\]{}|\\])*")
#: Characters a Zenoh key cannot hold (wildcards, verbatim-chunk ``@``), escaped as %XX in a channel.
_KEY_UNSAFE = re.compile(r"[%*$?#@\s]")
_EMPTY_CHUNK = "%-"


def channel_key(prefix: str, channel: str) -> str:
    """The Zenoh key of ``channel``: ``prefix/channel``, reserved characters and empty chunks escaped."""
    chunks = [
        _KEY_UNSAFE.sub(lambda m: f"%{ord(m.group()):02X}", c) if c else _EMPTY_CHUNK
        for c in channel.split("/")
    ]
    return f"{prefix}/{'/'.join(chunks)}"


def key_channel(prefix: str, key: str) -> str | None:
    """The channel a key under ``prefix`` carries (inverse of :func:`channel_key`); None if not ours."""
    if not key.startswith(prefix + "/"):
        return None
    out = []
    for chunk in key[len(prefix) + 1 :].split("/"):
        if chunk == _EMPTY_CHUNK:
            out.append("")
        else:
            out.append(re.sub(r"%([0-9A-F]{2})", lambda m: chr(int(m.group(1), 16)), chunk))
    return "/".join(out)


def literal_channel(regex: str) -> str | None:
    """The one channel an LCM channel regex matches when it is a literal (``alpha/MC_STATE``), else None."""
    if not _LITERAL.fullmatch(regex):
        return None
    return re.sub(r"\\(.)", r"\1", regex)


__all__ = ["channel_key", "key_channel", "literal_channel"]
