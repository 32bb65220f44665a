"""Deprecated name of :mod:`antalate_lcm.transports.datagram` (moved there by issue #26): docs/lan.md told
users to forge test datagrams with it, so it keeps working, with a warning, for one release."""

from antalate_lcm.base.deprecation import moved_module
from antalate_lcm.transports.datagram import Reassembler, channel_problem, fragments, short_datagram

__getattr__ = moved_module(__name__)
__all__ = ["Reassembler", "channel_problem", "fragments", "short_datagram"]
