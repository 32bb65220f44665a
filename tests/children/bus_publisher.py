"""Publish 200 telemetry messages (seq 0..199, mode "SIM") on ``alpha/TELEMETRY`` of the bus at URL.

python -m tests.children.bus_publisher URL
"""

from __future__ import annotations

import sys
import time

from antalate_lcm.core.bus import Buses
from antalate_lcm.msgs import telemetry_t


def main(url: str) -> None:
    b = Buses({"lan": url})
    for i in range(200):
        m = telemetry_t()
        m.header.seq = i
        m.lat = 32.0 + i * 1e-6
        m.mode = "SIM"
        b.publish("lan", "alpha/TELEMETRY", m)
        time.sleep(0.002)
    b.close()


if __name__ == "__main__":
    main(sys.argv[1])
