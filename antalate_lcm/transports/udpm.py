"""The ``udpm://`` transport (and liblcm's multi-port ``mpudpm://``): LCM over UDP multicast on a LAN.

liblcm sends (and fragments) a udpm bus's messages; antalate receives them itself, on the event loop's
own thread, without liblcm's receive thread.

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
kernel (`UdpmReceiver.filter`, a classic BPF filter on the source address and port): multicast
loops every datagram back to every socket of the group on the host, the sender's own included, and a
thousand simulated agents read their own 20,000 datagrams a second only to drop them by channel. The
same filter can drop the short messages of every channel whose last part (after its last ``/``) is
not one the process subscribes to: an agent process keeps a few commands out of every other agent
process's telemetry and state.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import ipaddress
import logging
import socket
import struct
from collections.abc import Callable, Sequence
from typing import ClassVar

from antalate_lcm.base.errors import AntalateError, MulticastUnavailable
from antalate_lcm.transports.base import LcmUrl, OptionCheck, Transport, int_option, port_problem
from antalate_lcm.transports.datagram import MAX_CHANNEL_LENGTH, SHORT_MAGIC_BYTES, Reassembler

#: The bus's logger: what a connection says of its socket is said in its name.
log = logging.getLogger("antalate.bus")

DEFAULT_UDPM = "239.255.76.67:7667"
_MULTICAST = ipaddress.IPv4Network("224.0.0.0/4")
_TTL = int_option("ttl", 0, 255, "an integer 0-255 (0 = this host only, 1 = the local network)")
_RECV_BUF = int_option("recv_buf_size", 1, 2**31 - 1, "a size in bytes, 1 to 2147483647")


class _Multicast(Transport):
    """What udpm and mpudpm share: a multicast ``GROUP:PORT`` and the routing table's say on failure."""

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        network = u.network or DEFAULT_UDPM
        group, sep, port = network.partition(":")
        try:
            address = ipaddress.IPv4Address(group)
        except ValueError:
            raise ValueError(
                f"a dotted IPv4 multicast group (224.0.0.0 to 239.255.255.255) before the port, not {group!r}"
            ) from None
        if address not in _MULTICAST:
            raise ValueError(f"a multicast group (224.0.0.0/4); {group} is a unicast address")
        if not sep:
            raise ValueError(f"a port after the group ({group}:7667)")
        problem = port_problem(port, "after the group")
        if problem:
            raise ValueError(problem)
        return LcmUrl(u.url, u.scheme, u.network, u.options, str(address), int(port))

    def failure(self, liblcm_said: Sequence[str] = ()) -> AntalateError:
        """ "No multicast route" (with the fix) only when the routing table really has none: that fix
        would be the wrong advice for a busy socket."""
        if multicast_route_missing(self.url):
            return MulticastUnavailable(self.url.url)
        return super().failure(liblcm_said)


class Udpm(_Multicast):
    """UDP multicast on the LAN (liblcm's ``lcm_udpm.c``): read from a socket of antalate's own
    (:class:`UdpmReceiver`), short messages sent from one (:class:`UdpmSender`), the rest by liblcm."""

    scheme = "udpm"
    options: ClassVar[dict[str, OptionCheck]] = {"ttl": _TTL, "recv_buf_size": _RECV_BUF}
    ready_means_message = True
    apart_by_port = True

    def receiver(self, reassembler: Reassembler | None = None) -> UdpmReceiver:
        """A socket of antalate's own receiving this bus (the error says the fix when it cannot open)."""
        try:
            return UdpmReceiver(self.url.url, reassembler)
        except OSError as exc:
            raise self.failure([f"receive socket: {exc}"]) from None

    def sender(self) -> UdpmSender:
        return UdpmSender(self.url.url)


class Mpudpm(_Multicast):
    """liblcm's multi-port udpm (``lcm_mpudpm.c``): channels spread over ``nports`` ports; liblcm's own."""

    scheme = "mpudpm"
    options: ClassVar[dict[str, OptionCheck]] = {
        "ttl": _TTL,
        "recv_buf_size": _RECV_BUF,
        "nports": int_option("nports", 1, 65535, "a number of ports >= 1"),
    }

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        u = super().check(u)
        if u.port + int(u.options.get("nports", "1")) - 1 > 65535:
            raise ValueError(f"ports up to 65535: {u.port} + nports={u.options['nports']} goes beyond")
        return u


def multicast_route_missing(u: LcmUrl) -> bool:
    """Whether this host has no route to ``u``'s multicast group (what liblcm's test connect() hits).

    A UDP connect() sends nothing: it only looks the destination up in the routing table.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.connect((u.host, u.port))
        except OSError as exc:
            return exc.errno in (errno.ENETUNREACH, errno.EHOSTUNREACH, errno.ENODEV)
    return False


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
    u = Udpm.parse(url)
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
        self.url = url
        self.reassembler = reassembler or Reassembler()
        #: (own address, topics) the socket's filter drops by (see :meth:`narrow`).
        self.applied: tuple[tuple[str, int] | None, frozenset[str] | None] = (None, None)
        #: False once the kernel refused a filter by topics: only the own datagrams are filtered, for good.
        self.by_topics = True
        #: The kernel refused any socket filter: every datagram is read, as liblcm's thread reads it.
        self.unfiltered = False

    @property
    def drops_own(self) -> bool:
        """The kernel drops this process's own datagrams (the reader need not)."""
        return self.applied[0] is not None

    def narrow(self, own: tuple[str, int] | None, topics: frozenset[str] | None) -> None:
        """Filter as :meth:`filter` says, as far as the kernel lets us: too many topics for one filter,
        or a filter by topics larger than the socket's option memory (ENOMEM: ``net.core.optmem_max``,
        charged by successive large filters), filters the own datagrams only; any other refusal (no
        socket filters, SO_LOCK_FILTER), none, said once. Never is an earlier, narrower filter left on
        the socket: it would drop, in the kernel, what a later subscription wants."""
        if self.unfiltered:
            return
        if not self.by_topics:
            topics = None
        if (own, topics) == self.applied:
            return
        try:
            if topics is not None and not self.filter(own, topics):
                topics = None
            if topics is None:
                self.filter(own, None)
        except OSError as exc:
            self._refused(own, topics, exc)
            return
        self.applied = (own, topics)

    def _refused(self, own: tuple[str, int] | None, topics: frozenset[str] | None, exc: OSError) -> None:
        if topics is not None and exc.errno == errno.ENOMEM:
            self.by_topics = False
            log.info("cannot filter datagrams on %s by topic in the kernel (%s): only its own", self.url, exc)
            try:
                self.filter(own, None)
            except OSError as again:
                exc = again
            else:
                self.applied = (own, None)
                return
        log.info("cannot filter datagrams on %s in the kernel (%s): reading all of them", self.url, exc)
        self.unfiltered = True
        # Off with any filter an earlier call attached (a locked one stays: not ours to change).
        with contextlib.suppress(OSError):
            self.filter(None, None)
        self.applied = (None, None)

    def fileno(self) -> int:
        return self.sock.fileno()

    def filter(self, own: tuple[str, int] | None, topics: frozenset[str] | None) -> bool:
        """Let the kernel drop what ``own`` (this process's `UdpmSender`) sends and, with ``topics``,
        every short message whose channel's last ``/``-part is none of them (both None: hear all).
        False (nothing changed) when that many topics do not fit a socket filter."""
        return _attach(self.sock, own, topics)

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


#: Classic BPF opcodes (linux/filter.h) and SKF_NET_OFF: offsets from the network header, so they
#: do not depend on where the kernel has the UDP header when the filter runs.
_LD_W, _LD_H, _LD_B = 0x20, 0x28, 0x30  # BPF_LD | BPF_W/H/B | BPF_ABS
_JEQ, _AND, _RET = 0x15, 0x54, 0x06  # BPF_JMP|BPF_JEQ|BPF_K, BPF_ALU|BPF_AND|BPF_K, BPF_RET|BPF_K
_NET = -0x100000
_ACCEPT, _DROP = 0xFFFFFFFF, 0
_CHANNEL = _NET + 20 + 8 + 8  # IPv4 header without options, UDP header, LC02 magic and seqno
_MAX_CODE = 4096  # BPF_MAXINSNS


def _topic_block(length: int, topics: list[bytes]) -> list[tuple[int, int, int, int]]:
    """Code for a channel of ``length`` bytes (its NUL found there): accept it when it is one of
    ``topics`` or ends with ``/`` and one of them, else drop."""
    code: list[tuple[int, int, int, int]] = []
    for topic in topics:
        m = len(topic)
        if m > length:
            continue
        at = _CHANNEL + length - m
        checks: list[tuple[int, int, int]] = []  # (load op, offset, value)
        k = 0
        while k < m:
            size = 4 if m - k >= 4 else 2 if m - k >= 2 else 1
            op = {4: _LD_W, 2: _LD_H, 1: _LD_B}[size]
            checks.append((op, at + k, int.from_bytes(topic[k : k + size], "big")))
            k += size
        if m < length:
            checks.append((_LD_B, at - 1, ord("/")))
        n = 2 * len(checks) + 1  # this topic's code: a load and a test per check, then accept
        for i, (op, offset, value) in enumerate(checks):
            code.append((op, 0, 0, offset))
            code.append((_JEQ, 0, n - 2 * i - 2, value))  # a mismatch: past this topic's accept
        code.append((_RET, 0, 0, _ACCEPT))
    code.append((_RET, 0, 0, _DROP))
    return code


def _program(own: tuple[str, int] | None, topics: frozenset[str] | None) -> list[tuple[int, int, int, int]]:
    """A classic BPF program: drop IPv4 datagrams from ``own`` (ip, port); with ``topics``, drop an
    ``LC02`` datagram unless its channel is a topic or ends with ``/`` and a topic. Anything else
    (a header with options, fragments, what is not LCM) is accepted: the reader deals with it."""
    code: list[tuple[int, int, int, int]] = [
        (_LD_B, 0, 0, _NET),
        (_AND, 0, 0, 0xF),  # IHL
        (_JEQ, 1, 0, 5),
        (_RET, 0, 0, _ACCEPT),  # IP options: not ours to judge
    ]
    if own is not None:
        ip = struct.unpack(">I", socket.inet_aton(own[0]))[0]
        code += [
            (_LD_W, 0, 0, _NET + 12),  # source address
            (_JEQ, 0, 3, ip),
            (_LD_H, 0, 0, _NET + 20),  # UDP source port
            (_JEQ, 0, 1, own[1]),
            (_RET, 0, 0, _DROP),  # this process's own datagram
        ]
    if topics is not None:
        names = sorted(t.encode("utf-8") for t in topics)
        code += [
            (_LD_W, 0, 0, _NET + 28),
            (_JEQ, 1, 0, int.from_bytes(SHORT_MAGIC_BYTES, "big")),
            (_RET, 0, 0, _ACCEPT),  # fragments and what is not LCM
        ]
        for length in range(MAX_CHANNEL_LENGTH + 1):  # the channel's NUL at _CHANNEL + length
            block = _topic_block(length, names)
            code.append((_LD_B, 0, 0, _CHANNEL + length))
            code.append((_JEQ, 0, len(block), 0))  # not the NUL: the next length
            code += block
        code.append((_RET, 0, 0, _ACCEPT))  # no NUL where a channel ends: the reader counts it
    else:
        code.append((_RET, 0, 0, _ACCEPT))
    return code


def _attach(sock: socket.socket, own: tuple[str, int] | None, topics: frozenset[str] | None) -> bool:
    """Filter ``sock`` as `_program` says (both None: no filter); False when the program would be
    too long for the kernel (too many topics) and nothing was changed."""
    if own is None and topics is None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, _SO_DETACH_FILTER, b"\0" * 4)
        except OSError as exc:
            if exc.errno != errno.ENOENT:  # ENOENT: no filter was attached, which is what is asked
                raise
        return True
    code = _program(own, topics)
    if len(code) > _MAX_CODE or any(jt > 255 or jf > 255 for _, jt, jf, _ in code):
        return False
    buf = ctypes.create_string_buffer(
        b"".join(struct.pack("HBBI", c, t, f, k & 0xFFFFFFFF) for c, t, f, k in code)
    )
    # The kernel copies the program: the buffer may go once setsockopt returns.
    sock.setsockopt(socket.SOL_SOCKET, _SO_ATTACH_FILTER, struct.pack("HL", len(code), ctypes.addressof(buf)))
    return True


class UdpmSender:
    """Sends the short messages of a ``udpm://`` bus as liblcm does, from a socket whose address is known.

    :meth:`publish` returns False for a message that does not fit one datagram or a channel liblcm
    would refuse: the caller then publishes it with liblcm (which fragments or reports it).
    """

    def __init__(self, url: str) -> None:
        u = Udpm.parse(url)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # As liblcm's send socket: the URL's TTL (0 = this host only) and loopback on, so other
            # processes of this host hear it.
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, int(u.options.get("ttl", "0")))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            # Not connected, as liblcm's ("don't use connect() on the actual transmit socket, because
            # linux then has problems multicasting to localhost", lcm_udpm.c): connected, a ttl=0
            # bus routed through lo reached no one. Bound to a port of its own; the source address
            # is the one the route gives, found with a connected socket that sends nothing.
            sock.bind(("0.0.0.0", 0))
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                probe.connect((u.host, u.port))
                source = probe.getsockname()[0]
        except OSError:
            sock.close()
            raise
        self.sock = sock
        #: (source address, port) of every datagram this sender sends.
        self.address: tuple[str, int] = (source, sock.getsockname()[1])
        sendto, group = sock.sendto, (u.host, u.port)
        self._send: Callable[[bytes], int] = lambda data: sendto(data, group)
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
