"""What every protocol emulator shares: its threads, the context manager, waiting on its snapshot, and
the motion a local-frame snapshot starts with.

The threads are the vehicle kit's `antalate_lcm.vehicles.kit.Workers`, the same the adapters run on,
so an emulator starts, stops and joins its loops exactly as the adapter it answers does.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from typing_extensions import Self

from antalate_lcm.vehicles.kit import Workers
from tests.harness.polling import wait_for

S = TypeVar("S")


@dataclass(frozen=True)
class Motion:
    """Where an emulated body is and how it moves, in its emulator's local frame (m, deg, m/s; the
    emulator's module docstring says which way the axes point): the first fields of its snapshot."""

    x: float
    y: float
    z: float
    yaw: float
    vx: float
    vy: float
    vz: float


class Emulator(ABC, Generic[S]):
    """An emulated vehicle with snapshots of type `S`; use as a context manager (`start`, `stop`)."""

    def __init__(self) -> None:
        self._workers = Workers()

    @abstractmethod
    def start(self) -> Self:
        """Open the emulator's transports and start its loops (`_workers`); a second call does nothing."""

    @abstractmethod
    def snapshot(self) -> S:
        """The emulated vehicle now, as one consistent value."""

    def _close_transports(self) -> None:
        """Close what `start` opened (sockets, memory links), after the loops have stopped."""

    def stop(self) -> None:
        """Stop the loops and release the transports (idempotent)."""
        self._workers.halt(timeout=5.0)
        self._close_transports()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait_until(self, predicate: Callable[[S], bool], timeout: float) -> bool:
        """``predicate(snapshot())`` polled with `tests.harness.polling.wait_for`: True once it holds,
        False if `timeout` s pass first."""
        return wait_for(lambda: predicate(self.snapshot()), timeout)
