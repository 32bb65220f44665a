"""The real djitellopy flies a short hop against the Tello at 192.168.10.1 (the emulator, in the other
namespace) and prints, as JSON, what it read back: battery, SDK version, heights, forward speed.

    python -m tests.children.djitellopy_flight
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any

from djitellopy import Tello


def main() -> dict[str, Any]:
    Tello.LOGGER.setLevel(logging.WARNING)
    t = Tello()  # 192.168.10.1, the emulator's address in the other namespace
    t.connect()
    out = {"battery": t.get_battery(), "sdk": t.query_sdk_version(), "battery_q": t.query_battery()}
    t.takeoff()
    time.sleep(0.15)
    out["h_flying"] = t.get_height()
    for _ in range(8):
        t.send_rc_control(0, 50, 0, 0)
        time.sleep(0.1)
    out["vgx"] = t.get_speed_x()
    t.send_rc_control(0, 0, 0, 0)
    t.land()
    time.sleep(0.15)
    out["h_landed"] = t.get_height()
    t.end()
    return out


if __name__ == "__main__":
    print(json.dumps(main()))
