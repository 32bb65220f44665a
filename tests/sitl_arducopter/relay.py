"""A TCP relay between the adapter and SITL's SERIAL0 that the test can cut or stall (a radio or a modem).

``pass`` forwards both ways; ``cut`` reads and drops everything (a radio out of range: the TCP
connection stays up, nothing arrives); ``stall`` reads and holds everything, and the next ``pass``
delivers it all at once, in order (a TCP link or a modem buffering through a dead spell, as a field
trial saw). The upstream connection to SITL is made when the adapter connects, so SITL -- which waits
for its first SERIAL0 client before it boots -- starts with the agent already connected.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from typing import Generic, TypeVar

MODES = ("pass", "cut", "stall")

#: What a relay holds while stalled, and hands back to be sent when it passes again.
Held = TypeVar("Held")


class _Modes(Generic[Held]):
    """The modes both relays share: ``set_mode`` checks the mode and, back to ``pass``, sends what the
    stall held, in order (outside the lock: a send may block)."""

    def __init__(self) -> None:
        self.mode = "pass"
        self._lock = threading.Lock()

    def _take_held(self) -> Held:
        """What is held, emptied (called with the lock held)."""
        raise NotImplementedError

    def _release(self, held: Held) -> None:
        raise NotImplementedError

    def set_mode(self, mode: str) -> None:
        if mode not in MODES:
            raise ValueError(f"relay mode {mode!r}: one of {MODES}")
        with self._lock:
            self.mode = mode
            if mode != "pass":
                return
            held = self._take_held()
        self._release(held)


class Relay(_Modes[list[tuple[socket.socket | None, bytes]]]):
    def __init__(self, listen_port: int, upstream_port: int, host: str = "127.0.0.1") -> None:
        super().__init__()
        self.upstream = (host, upstream_port)
        self._held: dict[str, bytearray] = {"up": bytearray(), "down": bytearray()}
        self._socks: dict[str, socket.socket] = {}  # "up": to SITL, "down": to the adapter
        self._server = socket.create_server((host, listen_port))
        self.port = self._server.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _take_held(self) -> list[tuple[socket.socket | None, bytes]]:
        flush = [(self._socks.get(k), bytes(b)) for k, b in self._held.items()]
        for b in self._held.values():
            b.clear()
        return flush

    def _release(self, held: list[tuple[socket.socket | None, bytes]]) -> None:
        for sock, data in held:
            if sock is not None and data:
                with contextlib.suppress(OSError):
                    sock.sendall(data)

    def _accept(self) -> None:
        while True:
            down, _ = self._server.accept()
            up = self._connect_upstream()
            with self._lock:
                self._socks = {"up": up, "down": down}
            threading.Thread(target=self._pump, args=(down, up, "up"), daemon=True).start()
            threading.Thread(target=self._pump, args=(up, down, "down"), daemon=True).start()

    def _connect_upstream(self) -> socket.socket:
        while True:
            try:
                return socket.create_connection(self.upstream, timeout=5)
            except OSError:
                time.sleep(0.1)

    def _pump(self, src: socket.socket, dst: socket.socket, key: str) -> None:
        src.settimeout(None)
        while True:
            try:
                data = src.recv(65536)
            except OSError:
                data = b""
            if not data:
                for s in (src, dst):
                    with contextlib.suppress(OSError):
                        s.close()
                return
            with self._lock:
                if self.mode == "cut":
                    continue
                if self.mode == "stall":
                    self._held[key] += data
                    continue
            with contextlib.suppress(OSError):
                dst.sendall(data)


class UdpRelay(_Modes[dict[str, list[bytes]]]):
    """`Relay`'s modes for a UDP link (PX4's offboard link): between a vehicle that sends to
    ``listen_port`` and an adapter listening (``udpin``) on ``adapter_port``.

    PX4 SITL instance N sends its offboard link to 14540+N from 14580+N (../shared/sitl/px4/README.txt):
    the relay takes 14540+N, forwards what PX4 sends to the adapter from a socket of its own, and what the
    adapter answers to wherever PX4 last sent from. ``stall`` holds datagrams and ``pass`` delivers them in
    order, as the TCP relay does with its bytes.
    """

    def __init__(self, listen_port: int, adapter_port: int, host: str = "127.0.0.1") -> None:
        super().__init__()
        self._held: dict[str, list[bytes]] = {"up": [], "down": []}
        self._vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._vehicle.bind((host, listen_port))
        self._adapter = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._adapter.bind((host, 0))
        self._adapter_addr = (host, adapter_port)
        self._vehicle_addr: tuple[str, int] | None = None
        threading.Thread(target=self._pump, args=("down",), daemon=True).start()
        threading.Thread(target=self._pump, args=("up",), daemon=True).start()

    def _take_held(self) -> dict[str, list[bytes]]:
        held = {k: list(v) for k, v in self._held.items()}
        for v in self._held.values():
            v.clear()
        return held

    def _release(self, held: dict[str, list[bytes]]) -> None:
        for key, datagrams in held.items():
            for data in datagrams:
                self._send(key, data)

    def _send(self, key: str, data: bytes) -> None:
        with contextlib.suppress(OSError):
            if key == "down":
                self._adapter.sendto(data, self._adapter_addr)
            elif self._vehicle_addr is not None:
                self._vehicle.sendto(data, self._vehicle_addr)

    def _pump(self, key: str) -> None:
        sock = self._vehicle if key == "down" else self._adapter
        while True:
            try:
                data, addr = sock.recvfrom(65536)
            except OSError:
                continue  # ICMP port unreachable while the adapter is not listening yet
            with self._lock:
                if key == "down":
                    self._vehicle_addr = addr
                if self.mode == "cut":
                    continue
                if self.mode == "stall":
                    self._held[key].append(data)
                    continue
            self._send(key, data)
