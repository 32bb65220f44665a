"""Receiving a ``udpm://`` bus on the event loop's own thread, without liblcm's receive thread.

liblcm reads a udpm socket on a thread of its own, queues each datagram and wakes the reader through
a pipe: two thread wake-ups per message, the second one in Python, and about 6 µs of that thread per
datagram even for one nobody subscribes to. antalate reads the socket here instead, on the executor's
loop: one wake-up, no C thread competing for the two cores of a field laptop, and a datagram nobody
wants (a process's own publications loop back) dropped after one ``recvfrom``
(``benchmarks/bus.py``, ``benchmarks/tui.py``, ``benchmarks/agents.py``). The socket is set up as
liblcm sets up its own (``_setup_recv_parts``: ``SO_REUSEADDR``, ``recv_buf_size`` as
``SO_RCVBUF``, bound to the group and port, the group joined on every interface), so it shares the
port with liblcm processes and the stock tools.

`UdpmSender` publishes what fits one datagram from a socket of its own, as liblcm's
``lcm_udpm_publish`` sends a short message (``LC02``, its sequence number, the channel and the
message; ``lcm_udpm.c``), and leaves anything larger to liblcm's fragmenting publish. Its socket's
address is known, so the process's own receive socket can drop what the process itself sent in the
kernel (`UdpmReceiver.ignore`, a classic BPF filter on the source address and port): multicast
loops every datagram back to every socket of the group on the host, the sender's own included, and a
thousand simulated agents read their own 20,000 datagrams a second only to drop them by channel.
"""

from __future__ import annotations

import ctypes
import socket
import struct
from collections.abc import Callable

from antalate_lcm.lcm_datagram import MAX_CHANNEL_LENGTH, SHORT_MAGIC_BYTES, Reassembler
from antalate_lcm.lcm_url import parse_lcm_url

#: The largest UDP payload; liblcm reads into 65,535 bytes too.
_DATAGRAM = 65_535
#: SO_RCVBUF asked for when the URL gives no ``recv_buf_size`` (the kernel caps it at
#: ``net.core.rmem_max``). liblcm asks for nothing, but its thread empties the socket into a ring
#: buffer of its own whatever Python is doing; here the kernel's buffer is the only queue.
DEFAULT_RCVBUF = 4 << 20
#: liblcm's LCM_SHORT_MESSAGE_MAX_SIZE: channel, its NUL and the message in one datagram at most.
SHORT_MESSAGE_MAX = 65_499
#: setsockopt options of Linux (asm-generic/socket.h); the socket module does not name them.
_SO_ATTACH_FILTER, _SO_DETACH_FILTER = 26, 27


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

    def ignore(self, address: tuple[str, int] | None) -> None:
        """Drop what ``address`` (this process's `UdpmSender`) sends, in the kernel; None: stop."""
        _ignore(self.sock, address)

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


def _own_datagram_filter(address: tuple[str, int]) -> tuple[bytes, ctypes.Array[ctypes.c_char]]:
    """A classic BPF program (``struct sock_fprog`` and its code) that drops IPv4 datagrams from
    ``address`` (ip, port) and accepts every other one. Offsets are from the network header
    (``SKF_NET_OFF``), so they do not depend on where the kernel has the UDP header; a header with
    options is accepted (never dropped by mistake)."""
    net = -0x100000  # SKF_NET_OFF
    ld_w, ld_h, ld_b = 0x20, 0x28, 0x30  # BPF_LD | BPF_W/H/B | BPF_ABS
    jeq, and_k, ret = 0x15, 0x54, 0x06  # BPF_JMP|BPF_JEQ|BPF_K, BPF_ALU|BPF_AND|BPF_K, BPF_RET|BPF_K
    ip = struct.unpack(">I", socket.inet_aton(address[0]))[0]
    code = [
        (ld_w, 0, 0, net + 12),  # source address
        (jeq, 0, 5, ip),  # another host: accept
        (ld_b, 0, 0, net),
        (and_k, 0, 0, 0xF),  # IHL
        (jeq, 0, 2, 5),  # IP options: accept
        (ld_h, 0, 0, net + 20),  # UDP source port
        (jeq, 1, 0, address[1]),  # ours: drop
        (ret, 0, 0, 0xFFFFFFFF),
        (ret, 0, 0, 0),
    ]
    buf = ctypes.create_string_buffer(
        b"".join(struct.pack("HBBI", c, t, f, k & 0xFFFFFFFF) for c, t, f, k in code)
    )
    return struct.pack("HL", len(code), ctypes.addressof(buf)), buf


def _ignore(sock: socket.socket, address: tuple[str, int] | None) -> None:
    """Drop datagrams from ``address`` on ``sock`` in the kernel (None: hear every sender again)."""
    if address is None:
        sock.setsockopt(socket.SOL_SOCKET, _SO_DETACH_FILTER, b"\0" * 4)
        return
    prog, code = _own_datagram_filter(address)
    sock.setsockopt(socket.SOL_SOCKET, _SO_ATTACH_FILTER, prog)  # the kernel copies the program
    del code


class UdpmSender:
    """Sends the short messages of a ``udpm://`` bus as liblcm does, from a socket whose address is known.

    :meth:`publish` returns False for a message that does not fit one datagram or a channel liblcm
    would refuse: the caller then publishes it with liblcm (which fragments or reports it).
    """

    def __init__(self, url: str) -> None:
        u = parse_lcm_url(url)
        if u.provider != "udpm":
            raise ValueError(f"not a udpm:// URL: {url!r}")
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # As liblcm's send socket: the URL's TTL (0 = this host only) and loopback on, so other
            # processes of this host hear it.
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, int(u.options.get("ttl", "0")))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            # Connected: the route (so the source address) is chosen once, and each send skips
            # parsing an address.
            sock.connect((u.host, u.port))
        except OSError:
            sock.close()
            raise
        self.sock = sock
        #: (source address, port) of every datagram this sender sends.
        self.address: tuple[str, int] = sock.getsockname()
        self._send = sock.send
        self._seqno = 0
        #: channel -> its bytes and NUL (bounded: a process publishes on a fixed set of channels).
        self._names: dict[str, bytes] = {}

    def publish(self, channel: str, data: bytes) -> bool:
        """Send one ``LC02`` datagram; False (nothing sent) when liblcm must send it instead."""
        name = self._names.get(channel)
        if name is None:
            name = channel.encode("utf-8") + b"\0"
            if len(name) > MAX_CHANNEL_LENGTH + 1:
                return False
            if len(self._names) < 100_000:
                self._names[channel] = name
        if len(name) + len(data) > SHORT_MESSAGE_MAX:
            return False
        seqno = self._seqno
        self._seqno = (seqno + 1) & 0xFFFFFFFF
        self._send(b"".join((SHORT_MAGIC_BYTES, _SEQNO(seqno), name, data)))
        return True

    def close(self) -> None:
        self.sock.close()


_SEQNO = struct.Struct(">I").pack
