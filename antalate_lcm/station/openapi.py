"""Print the station's OpenAPI document: ``python -m antalate_lcm.station.openapi > docs/openapi.json``.

The committed copy lets people read the protocol without running a station; a test fails when it
no longer matches what the code serves.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from ._app import create_app
from ._settings import MEMORY, StationSettings


def document() -> dict[str, Any]:
    """The OpenAPI document as served at ``/openapi.json`` (independent of settings)."""
    return create_app(StationSettings(db_path=MEMORY)).openapi()


def main() -> int:
    sys.stdout.write(json.dumps(document(), indent=2, ensure_ascii=False) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
