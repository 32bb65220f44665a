"""Connect to a PX4 on PORT, mirror a geofence into its GF_* parameters and print, as one JSON line,
the parameters before, the ones wanted, the problems the mirror reported and the parameters after
(tests/safety/test_fence_mirror_px4.py).

    python -m tests.children.px4_fence_mirror PORT
"""

from __future__ import annotations

import json
import sys
from typing import Any

from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.vehicles.px4 import Px4Adapter
from antalate_lcm.vehicles.px4.fence_mirror import ORDER, fence_parameters, mirror


def main(port: int) -> dict[str, Any]:
    fence = Geofence(((-30.0, -40.0), (-30.0, 40.0), (50.0, 40.0), (50.0, -40.0)), 0.0, 60.0, 2.0)
    ap = Px4Adapter({"connection": f"udpin:127.0.0.1:{port}", "connect_timeout": 90.0})
    ap.connect()
    try:
        before = ap.read_params(list(ORDER))
        wanted = fence_parameters(fence, (0.0, 0.0), "land")
        problems = mirror(ap, wanted)
        after = ap.read_params(list(ORDER))
    finally:
        ap.close()
    return {"before": before, "wanted": wanted, "problems": problems, "after": after}


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]))))
