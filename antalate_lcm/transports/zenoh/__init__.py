"""The ``zenoh://`` transport (docs/wan.md): :mod:`.config` (what a URL may say, the ``zenoh.Config`` it
becomes, TLS and credentials files), :mod:`.session` (:class:`ZenohLCM`, a Zenoh session that looks
like ``lcm.LCM`` to the bus and the bridge), :mod:`.groups` (the bridges' election), :mod:`.keys` (a channel's Zenoh key, pure).
"""

from __future__ import annotations

from antalate_lcm.transports.zenoh.config import (
    DEFAULT_LEASE_MS,
    ZENOH_NOT_LCM,
    read_credentials,
    readable_file,
    tls_settings,
    zenoh_endpoints_problem,
    zenoh_plain_endpoints,
)
from antalate_lcm.transports.zenoh.groups import GroupProof
from antalate_lcm.transports.zenoh.keys import channel_key, key_channel, literal_channel
from antalate_lcm.transports.zenoh.session import (
    BRIDGE_MARK,
    DEDUP_WINDOW,
    Zenoh,
    ZenohLCM,
    ZenohSubscription,
)

__all__ = [
    "BRIDGE_MARK",
    "DEDUP_WINDOW",
    "DEFAULT_LEASE_MS",
    "ZENOH_NOT_LCM",
    "GroupProof",
    "Zenoh",
    "ZenohLCM",
    "ZenohSubscription",
    "channel_key",
    "key_channel",
    "literal_channel",
    "read_credentials",
    "readable_file",
    "tls_settings",
    "zenoh_endpoints_problem",
    "zenoh_plain_endpoints",
]
