"""Messages the tests put on a bus by hand."""

from __future__ import annotations

from antalate_lcm.msgs import mc_state_t


def mc_state(state: int, seq: int = 0) -> mc_state_t:
    """An ``mc_state_t`` in ``state``, its header's sequence number ``seq``."""
    m = mc_state_t()
    m.state = state
    m.header.seq = seq
    return m
