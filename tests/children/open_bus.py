"""Open a bus on URL and let whatever it raises end the process (its traceback on stderr is what the
test reads).

    python -m tests.children.open_bus URL
"""

from __future__ import annotations

import sys

from antalate_lcm.core.bus import Buses

if __name__ == "__main__":
    Buses({"lan": sys.argv[1]}).open()
