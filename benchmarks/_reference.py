"""The reference workload a benchmark measures in its own run, so figures from two machines (or two
moments of one) can be compared as ratios: ``benchmarks/agents.py`` divides an agent's CPU by it,
``benchmarks/tui.py`` the console's CPU per message.
"""

from __future__ import annotations

import time

#: Messages the reference workload sends (about 0.1 s of CPU on the 2-core machine class).
REFERENCE_MESSAGES = 20_000


def reference(url: str) -> float:
    """CPU µs this thread spends per raw-lcm message: build, encode, publish (udpm), decode.

    The same message mix an agent sends, through liblcm rather than antalate: the yardstick the
    benchmarks' CPU figures are divided by. Thread CPU time, so a busy machine slows it the way
    it slows the measured process (caches, frequency) but preemption does not count.
    """
    import lcm

    from antalate_lcm.msgs import telemetry_t

    lc = lcm.LCM(url)
    # A thousand senders' messages in turn, as a thousand agents' are: a working set the size of
    # a swarm's, not one message hot in the cache.
    msgs = []
    for k in range(1000):
        msg = telemetry_t()
        msg.header.agent = f"ref-{k:03d}"
        msg.mode = "GUIDED"
        msgs.append((f"ref-{k:03d}/TELEMETRY", msg))
    t0 = time.thread_time()
    for i in range(REFERENCE_MESSAGES):
        channel, msg = msgs[i % 1000]
        msg.header.seq = i
        msg.lat = 32.0 + i * 1e-7
        data = msg.encode()
        lc.publish(channel, data)
        telemetry_t.decode(data)
    return (time.thread_time() - t0) / REFERENCE_MESSAGES * 1e6
