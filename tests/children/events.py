"""How the children report to their test: one JSON object a line on stdout, stamped with the seconds
since the child started, whole lines only (several threads emit)."""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

T0 = time.monotonic()
OUT = threading.Lock()


def emit(**event: Any) -> None:
    event["t"] = round(time.monotonic() - T0, 3)
    with OUT:
        sys.stdout.write(json.dumps(event) + "\n")
        sys.stdout.flush()
