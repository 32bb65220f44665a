"""Receiving a ``udpm://`` bus on the event loop's own thread, without liblcm's receive thread.

liblcm reads a udpm socket on a thread of its own, queues each datagram and wakes the reader through
a pipe: two thread wake-ups per message, the second one in Python, and about 6 µs of that thread per
datagram even for one nobody subscribes to. antalate reads the socket here instead, on the executor's
loop: one wake-up, no C thread competing for the two cores of a field laptop, and a datagram nobody
wants (a process's own publications loop back) dropped after one ``recvfrom``
(``benchmarks/bus.py``, ``benchmarks/tui.py``, ``benchmarks/agents.py``). The socket is set up as
liblcm sets up its own (``_setup_recv_parts``: ``SO_REUSEADDR``, ``recv_buf_size`` as
``SO_RCVBUF``, bound to the group and port, the group joined on every interface), so it shares the
port with liblcm processes and the stock tools. Publishing stays with liblcm.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Callable

from antalate_lcm.lcm_datagram import SHORT_MAGIC_BYTES, Reassembler
from antalate_lcm.lcm_url import parse_lcm_url

#: The largest UDP payload; liblcm reads into 65,535 bytes too.
_DATAGRAM = 65_535
#: SO_RCVBUF asked for when the URL gives no ``recv_buf_size`` (the kernel caps it at
#: ``net.core.rmem_max``). liblcm asks for nothing, but its thread empties the socket into a ring
#: buffer of its own whatever Python is doing; here the kernel's buffer is the only queue.
DEFAULT_RCVBUF = 4 << 20


def udpm_socket(url: str) -> socket.socket:
    """A non-blocking socket receiving the group of a ``udpm://`` URL, as liblcm's receive socket."""
    u = parse_lcm_url(url)
    if u.provider != "udpm":
        raise ValueError(f"not a udpm:// URL: {url!r}")
    group, port = u.host, u.port
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        rcvbuf = int(u.options.get("recv_buf_size", "0")) or DEFAULT_RCVBUF
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        sock.bind((group, port))
        mreq = struct.pack("=4sl", socket.inet_aton(group), socket.INADDR_ANY)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    return sock


class UdpmReceiver:
    """A udpm socket and its reassembler; :meth:`drain` hands every complete message to ``deliver``."""

    def __init__(self, url: str, reassembler: Reassembler | None = None) -> None:
        self.sock = udpm_socket(url)
        self.reassembler = reassembler or Reassembler()

    def fileno(self) -> int:
        return self.sock.fileno()

    def drain(self, deliver: Callable[[str, bytes], None], limit: int) -> int:
        """Read up to ``limit`` datagrams that are waiting (never blocks); returns how many were read."""
        recvfrom = self.sock.recvfrom
        reassembler = self.reassembler
        short = reassembler.short
        n = 0
        while n < limit:
            try:
                datagram, sender = recvfrom(_DATAGRAM)
            except BlockingIOError:
                break
            n += 1
            if datagram[:4] == SHORT_MAGIC_BYTES and len(datagram) >= 8:
                message = short(datagram)  # the common case, without feed()'s dispatch
            else:
                message = reassembler.feed(datagram, sender)
            if message is not None:
                deliver(*message)
        return n

    def close(self) -> None:
        self.sock.close()
