"""``memory://NAME``: a cflib link driver to a peer in this process, so the whole cflib stack runs with no radio.

cflib picks a link's driver by offering the URI to each class in ``cflib.crtp.CLASSES`` in turn (a
driver raises ``WrongUriType`` for a scheme not its own; ``init_drivers`` fills the list). `install`
adds `MemoryDriver` to that list, and the adapter installs it with cflib's own drivers, so a
``uri = "memory://NAME"`` in ``[hlc.autopilot_params]`` reaches whatever peer a `MemoryLink` registered
under ``NAME`` -- as ``httpx.MockTransport`` stands in for the network under an unchanged client. The
peer sees each packet exactly as the ``udp://`` driver would put it in a datagram (the CRTP header byte,
then up to 30 bytes of payload) and answers with `MemoryLink.push` in the same form, so a CRTP
emulator written for UDP serves both. Nothing here is a radio model: packets are neither lost nor
resent.

This module imports cflib; only the adapter's ``connect`` and tests import it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from cflib.crtp import CLASSES
from cflib.crtp.crtpdriver import CRTPDriver
from cflib.crtp.crtpstack import CRTPPacket
from cflib.crtp.exceptions import WrongUriType

from antalate_lcm.vehicles.kit.memory import MemoryPipe

SCHEME = "memory://"

_links: dict[str, MemoryLink] = {}
_links_lock = threading.Lock()


class MemoryLink:
    """The peer side of ``memory://NAME``: `handler` gets every packet cflib sends; `push` answers it.

    `handler` runs on cflib's sending thread and should return quickly (queue the packet if the
    peer needs time). Registering a name that is in use replaces nothing: it raises `ValueError`.
    Each driver that opens the link gets its own `kit.MemoryPipe` to the peer: one a closed driver
    left behind can neither send nor take the next driver's packets.
    """

    def __init__(self, name: str, handler: Callable[[bytes], None]) -> None:
        self.name = name
        self._handler = handler
        self._pipe: MemoryPipe[bytes, bytes] | None = None  # the open driver's, while one is connected
        with _links_lock:
            if name in _links:
                raise ValueError(f"a memory link named {name!r} is already registered")
            _links[name] = self

    @property
    def uri(self) -> str:
        return SCHEME + self.name

    @property
    def connected(self) -> bool:
        """A cflib driver has this link open (packets pushed now reach it)."""
        return self._pipe is not None

    def push(self, packet: bytes) -> None:
        """One packet to cflib (header byte + payload); dropped while no driver has the link open."""
        pipe = self._pipe
        if pipe is not None and packet:
            pipe.push(bytes(packet))

    def close(self) -> None:
        """Unregister the name; a driver still open receives nothing more."""
        with _links_lock:
            if _links.get(self.name) is self:
                del _links[self.name]
        self._pipe = None

    def _attach(self) -> MemoryPipe[bytes, bytes]:
        pipe: MemoryPipe[bytes, bytes] = MemoryPipe(self._handler)
        self._pipe = pipe
        return pipe

    def _detach(self, pipe: MemoryPipe[bytes, bytes]) -> None:
        pipe.close()
        if self._pipe is pipe:
            self._pipe = None


class MemoryDriver(CRTPDriver):  # type: ignore[misc]  # cflib is untyped
    """cflib's view of a `MemoryLink`: the CRTPDriver calls cflib's link thread makes."""

    def __init__(self) -> None:
        super().__init__()
        self.needs_resending = False  # an in-memory link loses nothing
        self._link: MemoryLink | None = None
        self._pipe: MemoryPipe[bytes, bytes] = MemoryPipe(lambda _packet: None, closed=True)

    def connect(self, uri: str, _link_statistics: Any, _link_error: Any) -> None:
        # cflib passes its callbacks positionally; an in-memory link has no statistics and no radio errors.
        if not uri.startswith(SCHEME):
            raise WrongUriType("not a memory:// URI")
        name = uri[len(SCHEME) :]
        with _links_lock:
            link = _links.get(name)
        if link is None:
            raise ConnectionError(f"no memory link named {name!r} is registered (MemoryLink({name!r}, ...))")
        self._pipe = link._attach()
        self._link = link

    def send_packet(self, pk: Any) -> None:
        if self._link is not None:
            self._pipe.send(bytes([pk.header]) + bytes(pk.data))

    def receive_packet(self, wait: float = 0) -> CRTPPacket | None:
        raw = self._pipe.take(None if wait < 0 else wait)
        return None if raw is None else CRTPPacket(raw[0], raw[1:])

    def get_status(self) -> str:
        return "in-process peer" if self._link is not None else "not connected"

    def get_name(self) -> str:
        return "memory"

    def scan_interface(self, address: Any = None) -> list[list[str]]:
        with _links_lock:
            return [[SCHEME + name, ""] for name in _links]

    def enum(self) -> list[str]:
        return []

    def get_help(self) -> str:
        return "memory://NAME: the MemoryLink registered under NAME in this process"

    def close(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            link._detach(self._pipe)


def install() -> None:
    """Add `MemoryDriver` to cflib's driver list (idempotent; drivers already there keep their order)."""
    with _links_lock:
        if MemoryDriver not in CLASSES:
            CLASSES.append(MemoryDriver)
