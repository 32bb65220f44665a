"""Send 50 datagrams of garbage that starts like a MAVLink 2 frame (0xFD, then 60 random bytes) to
127.0.0.1:PORT.

    python -m tests.children.mavlink_garbage PORT
"""

from __future__ import annotations

import os
import socket
import sys


def main(port: int) -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for _ in range(50):
        s.sendto(b"\xfd" + os.urandom(60), ("127.0.0.1", port))


if __name__ == "__main__":
    main(int(sys.argv[1]))
