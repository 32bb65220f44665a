"""Connect a Tello adapter with default parameters and print the error it raised, if any
(``TYPE message``): a second process in a namespace where another one holds port 8889.

    python -m tests.children.tello_connect
"""

from __future__ import annotations

from antalate_lcm.vehicles.tello import TelloAdapter


def main() -> None:
    try:
        TelloAdapter({}).connect()
    except Exception as exc:
        print(type(exc).__name__, exc)


if __name__ == "__main__":
    main()
