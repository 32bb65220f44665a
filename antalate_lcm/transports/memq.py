"""The ``memq://`` transport: liblcm's in-process queue, an agent's private bus.

Nothing outside the process can write to it, so the exposure policy lets an unsigned node consume
from it; the bus delivers its messages on its own loop (:mod:`antalate_lcm.core.bus`), never through
liblcm's queue.
"""

from __future__ import annotations

from antalate_lcm.transports.base import LcmUrl, Transport


class Memq(Transport):
    """liblcm's ``lcm_memq.c``: in-process only, no network and no options."""

    scheme = "memq"
    network_reachable = False
    ready_means_message = True
    in_process = True
    crosses_processes = False

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        if u.network:
            raise ValueError(f"nothing after memq:// (it is private to the process), not {u.network!r}")
        return u
