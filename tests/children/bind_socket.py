"""Bind a socket inside a network namespace and hand its descriptor back to the test process over the
Unix socket it inherited (tests/harness/netns.py's ``NetNamespace.socket``).

    python -m tests.children.bind_socket udp|tcp HOST PORT UNIX_FD
"""

from __future__ import annotations

import socket
import sys


def main(kind: str, host: str, port: int, unix_fd: int) -> None:
    unix = socket.socket(fileno=unix_fd)
    if kind == "udp":
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    else:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((host, port))
    if kind == "tcp":
        s.listen(8)
    socket.send_fds(unix, [b"ok"], [s.fileno()])


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
