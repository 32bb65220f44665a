"""What MAVProxy forwards on an --out: listen on PORT and print, as JSON, the last GLOBAL_POSITION_INT
(lat, lon) of each system id, once N system ids were heard for a second (or after T s).

    python -m tests.children.mavlink_listen PORT N T
"""

from __future__ import annotations

import json
import sys
import time

from pymavlink import mavutil


def main(port: int, count: int, seconds: float) -> dict[int, tuple[int, int]]:
    link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    last: dict[int, tuple[int, int]] = {}
    end, full = time.monotonic() + seconds, None
    while time.monotonic() < end and (full is None or time.monotonic() < full + 1):
        if full is None and len(last) >= count:
            full = time.monotonic()
        m = link.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=0.5)
        if m is not None:
            last[m.get_srcSystem()] = (m.lat, m.lon)
    return last


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]))))
