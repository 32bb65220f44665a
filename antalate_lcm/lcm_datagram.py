"""Deprecated: moved to :mod:`antalate_lcm.transports.datagram` (issue 26); this name stays for one
release because docs/lan.md told users to forge test datagrams with it."""

from __future__ import annotations

import warnings

from antalate_lcm.transports.datagram import Reassembler, channel_problem, fragments, short_datagram

warnings.warn(
    "antalate_lcm.lcm_datagram is deprecated: import antalate_lcm.transports.datagram",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["Reassembler", "channel_problem", "fragments", "short_datagram"]
