"""The in-memory link seam every adapter's tests plug a peer into, as ``httpx.MockTransport`` does.

A `MemoryPipe` connects an adapter's link to a peer in the same process -- a scripted vehicle or a
protocol emulator -- with no socket: what the adapter sends is handed to the peer's callable on the
sending thread, what the peer sends queues until the adapter takes it, and a closed pipe refuses to
send and drops what the peer still sends (a datagram to nobody). Each protocol's ``MemoryLink``
(`mavlink.link`: pymavlink frames, `tello.link`: SDK text, `crazyflie.memory`: CRTP packets) is this
pipe plus its framing, so the adapter runs exactly as over its real link, only without one.
"""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import Generic, TypeVar

from antalate_lcm.base.errors import LinkClosed

__all__ = ["MemoryPipe"]

Out = TypeVar("Out")
In = TypeVar("In")


class MemoryPipe(Generic[Out, In]):
    """Ours to `peer` (`send`), the peer's to us (`push`, then `take` or `drain`); thread-safe.

    `peer` runs on the sending thread and should return quickly (queue the item if it needs time).
    """

    def __init__(self, peer: Callable[[Out], None], *, closed: bool = False) -> None:
        self._peer = peer
        self._inbox: queue.SimpleQueue[In] = queue.SimpleQueue()
        self.closed = closed

    def send(self, item: Out) -> None:
        """`item` to the peer; `LinkClosed` (an `OSError`) once the pipe is closed."""
        if self.closed:
            raise LinkClosed("memory link closed")
        self._peer(item)

    def push(self, item: In) -> None:
        """`item` from the peer, taken in order; dropped while the pipe is closed."""
        if not self.closed:
            self._inbox.put(item)

    def take(self, timeout: float | None) -> In | None:
        """The peer's next item, None after `timeout` s (0: do not wait; None: wait for one)."""
        try:
            if timeout == 0:
                return self._inbox.get(block=False)
            return self._inbox.get(timeout=timeout)
        except queue.Empty:
            return None

    def drain(self) -> list[In]:
        """Everything the peer pushed and nobody took yet, oldest first."""
        items: list[In] = []
        while (item := self.take(0)) is not None:
            items.append(item)
        return items

    def open(self) -> None:
        """Usable again (after `close`)."""
        self.closed = False

    def close(self) -> None:
        """Refuse sends and drop the peer's pushes from now on (idempotent)."""
        self.closed = True
