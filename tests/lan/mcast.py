"""Raw LCM traffic for the topology tests, run inside a host: ``send`` or ``recv``, one JSON line out.

    python -m tests.lan.mcast recv URL SECONDS          -> {"received": {channel: n}}
    python -m tests.lan.mcast send URL CHANNEL N PERIOD -> {"sent": n, "errors": n, "error": "..."}

A send that fails (link down: ENETUNREACH) is counted, not fatal, exactly as the antalate bus does.
"""

from __future__ import annotations

import json
import sys
import time

import lcm


def main(argv: list[str]) -> int:
    mode, url = argv[0], argv[1]
    lc = lcm.LCM(url)
    if mode == "recv":
        counts: dict[str, int] = {}

        def on_msg(channel: str, _data: bytes) -> None:
            if channel != "LCM_SELF_TEST":  # every new LCM instance multicasts one
                counts[channel] = counts.get(channel, 0) + 1

        lc.subscribe(".*", on_msg).set_queue_capacity(100_000)
        print(json.dumps({"ready": True}), flush=True)
        end = time.monotonic() + float(argv[2])
        while time.monotonic() < end:
            lc.handle_timeout(50)
        print(json.dumps({"received": counts}), flush=True)
        return 0
    channel, n, period = argv[2], int(argv[3]), float(argv[4])
    sent = errors = 0
    last = ""
    for _ in range(n):
        try:
            lc.publish(channel, b"antalate lan test")
            sent += 1
        except OSError as exc:
            errors += 1
            last = str(exc)
        time.sleep(period)
    print(json.dumps({"sent": sent, "errors": errors, "error": last}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
