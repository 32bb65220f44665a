"""The emulated ArduCopter (tests/emulators/mavlink_vehicle.py) as a process in the test's namespace,
driven by JSON lines, so a test can read the vehicle's own state (not what the link reports).

``python -m tests.security.mav_vehicle --udp-port P --udp-target HOST:PORT --signing-key HEX``.
Requests: ``{"op": "snapshot"}`` -> the `VehicleSnapshot` fields plus ``signing_rejected`` and the
count of each message type received.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from dataclasses import asdict

from tests.emulators.mavlink_vehicle import BRISK, MavlinkVehicle


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--udp-port", type=int, required=True)
    parser.add_argument("--udp-target", required=True)
    parser.add_argument("--signing-key", default=None)
    parser.add_argument("--home", default="32.7767,35.0231")
    args = parser.parse_args()
    host, _, port = args.udp_target.rpartition(":")
    lat, lon = (float(v) for v in args.home.split(","))
    vehicle = MavlinkVehicle(
        "127.0.0.1",
        args.udp_port,
        None,
        udp_target=(host, int(port)),
        home_lat=lat,
        home_lon=lon,
        signing_key=bytes.fromhex(args.signing_key) if args.signing_key else None,
        **BRISK,
    )
    with vehicle:
        print(json.dumps({"ok": True, "ready": True}), flush=True)
        for line in sys.stdin:
            req = json.loads(line)
            if req["op"] == "snapshot":
                snap = asdict(vehicle.snapshot())
                counts = Counter(r.type for r in vehicle.received)
                reply = {
                    "ok": True,
                    "snapshot": snap,
                    "signing_rejected": vehicle.signing_rejected,
                    "received": dict(counts),
                }
            else:
                reply = {"ok": False, "error": f"unknown op {req['op']}"}
            print(json.dumps(reply, default=str), flush=True)


if __name__ == "__main__":
    main()
