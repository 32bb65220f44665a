"""Open each bus URL given and print, as one JSON object, "opened" or the antalate error each gave,
plus what a routed group that liblcm refused for another reason is blamed on.

    python -m tests.children.open_buses URL...
"""

from __future__ import annotations

import json
import sys

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.transports import open_failure, open_lcm


def main(urls: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for url in urls:
        try:
            open_lcm(url).fileno()
            out[url] = "opened"
        except AntalateError as exc:
            out[url] = type(exc).__name__ + ": " + str(exc).splitlines()[0]
    # liblcm failing for another reason on a routed group must not be blamed on the route
    refused = open_failure("udpm://239.255.76.68:7668", ["Couldn't create LCM"])
    out["routed group, liblcm refused"] = type(refused).__name__
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:])))
