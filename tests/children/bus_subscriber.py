"""Subscribe to ``alpha/TELEMETRY`` on the bus at URL, print ``ready``, then, once 200 messages came (or
10 s passed), one line: how many came and either whether they came in order (``order``) or how many
datagrams failed to decode (``decode-errors``).

    python -m tests.children.bus_subscriber URL order|decode-errors
"""

from __future__ import annotations

import sys
import time

from antalate_lcm.core.bus import Buses
from antalate_lcm.msgs import telemetry_t


def main(url: str, report: str) -> None:
    b = Buses({"lan": url})
    got: list[int] = []

    def on_telemetry(_channel: str, m: telemetry_t) -> None:
        got.append(m.header.seq)

    b.subscribe("lan", "alpha/TELEMETRY", telemetry_t, on_telemetry)
    print("ready", flush=True)
    deadline = time.time() + 10
    while len(got) < 200 and time.time() < deadline:
        time.sleep(0.01)
    if report == "order":
        print(len(got), got == list(range(200)), flush=True)
    else:
        print(len(got), b.decode_errors().get("alpha/TELEMETRY", 0), flush=True)
    b.close()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
