"""The link to the vehicle: send a pymavlink message, receive one, close (the adapter's only I/O).

`MavLink` is what `MavlinkAdapter` talks through. `PymavlinkLink` is the real one, pymavlink's
``mavlink_connection`` over a serial port, UDP or TCP, with MAVLink 2 signing. `MemoryLink` carries the
same frames through memory, for tests without SITL or sockets (as httpx ships ``MockTransport``): every
message is framed by pymavlink's codec and the peer's bytes are parsed by it, so what a test exercises
is the real wire format, signatures included::

    link = MemoryLink.answering(my_vehicle)        # my_vehicle(msg) -> the messages it answers with
    ap = MavlinkAdapter(params, link=lambda _params: link)

A byte-level peer (an emulator with its own parser) uses ``MemoryLink(peer_write)`` and hands its
output to `MemoryLink.feed`.
"""

from __future__ import annotations

import abc
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.base.errors import LinkClosed as LinkClosed
from antalate_lcm.base.errors import PeerClosed as PeerClosed
from antalate_lcm.vehicles.kit.memory import MemoryPipe
from antalate_lcm.vehicles.mavlink.signing import allow_unsigned, verify_signature_first

log = logging.getLogger("antalate.autopilot.mavlink")

__all__ = ["LinkClosed", "MavLink", "MemoryLink", "PymavlinkLink", "PeerClosed"]


class MavLink(abc.ABC):
    """One link to one vehicle. `send` may be called from any thread; one thread calls `recv`.

    Errors are `OSError`s: the adapter reopens a link whose `recv` raised.
    """

    @abc.abstractmethod
    def send(self, msg: Any) -> None:
        """Frame and write one pymavlink message (raises `OSError` if the link cannot take it)."""

    @abc.abstractmethod
    def recv(self, timeout: float) -> Any | None:
        """The next decoded message (``BAD_DATA`` included: a failed signature is one), None after `timeout` s."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the link; idempotent."""


def _sign(codec: Any, key: bytes) -> None:
    """Sign everything `codec` sends with `key` and drop what arrives unsigned or badly signed."""
    codec.signing.secret_key = key
    codec.signing.sign_outgoing = True
    codec.signing.allow_unsigned_callback = allow_unsigned
    codec.signing.timestamp = max(codec.signing.timestamp, int((time.time() - 1420070400) * 1e5))
    verify_signature_first(codec)


class PymavlinkLink(MavLink):
    """pymavlink's ``mavlink_connection`` (serial, ``udpin:``/``udpout:``, ``tcp:``); opened by the constructor."""

    def __init__(
        self,
        connection: str,
        *,
        source_system: int,
        source_component: int,
        baud: int = 57600,
        signing_key: bytes | None = None,
    ) -> None:
        self.connection = connection
        if signing_key is not None and "MAVLINK20" not in os.environ:
            # Signing needs MAVLink 2 from the first byte: pymavlink's switch on the first v2 frame it
            # hears replaces its codec and would drop the signing state. (pymavlink sets the same
            # process-wide switch itself as soon as it hears MAVLink 2.)
            os.environ["MAVLINK20"] = "1"
            mavutil.set_dialect("ardupilotmega")
        conn = mavutil.mavlink_connection(
            connection,
            baud=baud,
            source_system=source_system,
            source_component=source_component,
            autoreconnect=False,
            retries=0,
        )
        if signing_key is not None:
            if conn.WIRE_PROTOCOL_VERSION != "2.0":
                conn.close()
                raise ValueError("MAVLink 2 signing needs MAVLink 2, but pymavlink opened a MAVLink 1 codec")
            conn.setup_signing(signing_key, sign_outgoing=True, allow_unsigned_callback=allow_unsigned)
            verify_signature_first(conn.mav)
        if connection.startswith(("tcp:", "uds:", "unix:")):
            # pymavlink only prints on EOF and keeps returning nothing: make it an error we handle.
            def closed_by_peer() -> None:
                raise PeerClosed(f"{connection} closed by the peer")

            conn.handle_eof = closed_by_peer
            conn.handle_disconnect = closed_by_peer
        self._conn: Any = conn

    @property
    def codec(self) -> Any:
        """The pymavlink ``MAVLink`` object framing what is sent (replaced when pymavlink hears MAVLink 2)."""
        return self._conn.mav

    def send(self, msg: Any) -> None:
        codec = self._conn.mav  # looked up each time: pymavlink swaps it when it switches to MAVLink 2
        module = sys.modules[type(codec).__module__]
        if module is not mav:
            # Until pymavlink hears MAVLink 2 it frames MAVLink 1: the same message from its own dialect.
            msg = _convert(msg, module)
        codec.send(msg)

    def recv(self, timeout: float) -> Any | None:
        return self._conn.recv_match(blocking=True, timeout=timeout)

    def close(self) -> None:
        self._conn.close()


def _convert(msg: Any, dialect: Any) -> Any:
    """`msg` as the same message of another pymavlink dialect module (MAVLink 1, or ``all``)."""
    cls = getattr(dialect, type(msg).__name__)
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        value = getattr(msg, name)
        args.append(value.encode("ascii") if ftype == "char" and isinstance(value, str) else value)
    return cls(*args)


class _Writer:
    """The "file" a pymavlink codec writes its frames to."""

    def __init__(self, write: Callable[[bytes], None]) -> None:
        self.write_bytes = write

    def write(self, buf: bytes) -> None:
        self.write_bytes(bytes(buf))


class MemoryLink(MavLink):
    """A link through memory (`kit.MemoryPipe`): our frames go to `peer` (bytes), the peer's come back by `feed`.

    Both directions are real MAVLink 2 frames made and parsed by pymavlink (signed with `signing_key`),
    so the adapter runs exactly as over a socket, only without one. `feed` may be called from any thread.
    """

    def __init__(
        self,
        peer: Callable[[bytes], None],
        *,
        source_system: int = 245,
        source_component: int = mav.MAV_COMP_ID_ONBOARD_COMPUTER,
        signing_key: bytes | None = None,
    ) -> None:
        self._pipe: MemoryPipe[bytes, Any] = MemoryPipe(peer)
        self._send_lock = threading.Lock()
        self._parse_lock = threading.Lock()
        self._encoder = mav.MAVLink(
            _Writer(self._pipe.send), srcSystem=source_system, srcComponent=source_component
        )
        self._decoder = mav.MAVLink(None, srcSystem=source_system, srcComponent=source_component)
        self._decoder.robust_parsing = True
        if signing_key is not None:
            _sign(self._encoder, signing_key)
            _sign(self._decoder, signing_key)

    @classmethod
    def answering(
        cls,
        handler: Callable[[Any], Iterable[Any]],
        *,
        system: int = 1,
        component: int = mav.MAV_COMP_ID_AUTOPILOT1,
        signing_key: bytes | None = None,
        **kwargs: Any,
    ) -> MemoryLink:
        """A link to a scripted vehicle: ``handler(msg)`` gets every message we send, decoded, and returns
        the messages the vehicle answers with (framed as `system`/`component`, signed with `signing_key`).
        `MemoryLink.push` sends the vehicle's unsolicited messages (telemetry)."""
        vehicle = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        vehicle.robust_parsing = True
        if signing_key is not None:
            _sign(vehicle, signing_key)
        lock = threading.Lock()

        def peer(data: bytes) -> None:
            with lock:
                received = vehicle.parse_buffer(data) or []
            for msg in received:
                if msg.get_type() == "BAD_DATA":
                    continue
                try:
                    replies = list(handler(msg))
                except Exception:  # a test's vehicle failing must show, not end the sender's thread
                    log.exception("MemoryLink handler failed on %s", msg.get_type())
                    continue
                for reply in replies:
                    link.push(reply)

        def push(msg: Any) -> None:
            with lock:
                frame = msg.pack(vehicle)
                vehicle.seq = (vehicle.seq + 1) % 256
            link.feed(frame)

        link = cls(peer, signing_key=signing_key, **kwargs)
        link._push = push
        return link

    _push: Callable[[Any], None] | None = None

    def push(self, msg: Any) -> None:
        """Send `msg` as the vehicle of `answering` (framed and parsed like everything else)."""
        if self._push is None:
            raise TypeError("push() needs a link made by MemoryLink.answering; feed() takes a peer's bytes")
        self._push(msg)

    def feed(self, data: bytes) -> None:
        """Bytes from the peer: parsed now, received by `recv` in order (dropped once closed)."""
        if self._pipe.closed:
            return
        with self._parse_lock:
            received = self._decoder.parse_buffer(data) or []
        for msg in received:
            self._pipe.push(msg)

    def send(self, msg: Any) -> None:
        if self._pipe.closed:
            raise LinkClosed("memory link closed")
        with self._send_lock:
            self._encoder.send(msg)

    def recv(self, timeout: float) -> Any | None:
        if self._pipe.closed:
            raise LinkClosed("memory link closed")
        return self._pipe.take(timeout)

    @property
    def closed(self) -> bool:
        return self._pipe.closed

    def close(self) -> None:
        self._pipe.close()
