"""`LinkedAdapter`: what every vehicle adapter is built from, so each one is params + protocol + link.

Every adapter (`mavlink`, `px4`, `tello`, `crazyflie`) repeats the same skeleton around its protocol:
parse the ``[hlc.autopilot_params]`` into its model in the constructor (as the config loader does),
open its link through an opener the caller may replace (a `memory.MemoryPipe`-backed link in tests,
as ``httpx.MockTransport`` stands in for the network), run worker threads that `close` stops, and
report how long ago the vehicle was last heard. That skeleton lives here once; the adapter keeps
only what its vehicle makes different.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar, cast

from pydantic import BaseModel

from antalate_lcm.vehicles.base import Clock, VehicleAdapter
from antalate_lcm.vehicles.kit.params import parse_params

__all__ = ["LinkAge", "LinkedAdapter", "Workers"]

P = TypeVar("P", bound=BaseModel)
L = TypeVar("L")


class LinkAge:
    """When the vehicle was last heard, on the adapter's clock: `VehicleState.link_age`.

    Infinite until the first message: a vehicle never heard is as lost as one long silent.
    """

    __slots__ = ("_clock", "heard_at")

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self.heard_at: float | None = None

    def heard(self, at: float | None = None) -> None:
        """The vehicle spoke now (or at `at`, a time of the same clock)."""
        self.heard_at = self._clock() if at is None else at

    def __call__(self) -> float:
        """Seconds since the vehicle was last heard (inf before the first time)."""
        at = self.heard_at
        return math.inf if at is None else max(0.0, self._clock() - at)


class Workers:
    """An adapter's (or emulator's) daemon threads and the event that stops them.

    `start` clears the event and starts the loops, `halt` sets it and joins them -- except the calling
    thread itself, so a loop may close its own adapter. A loop waits on `stop` (``stop.wait(period)``)
    so that `halt` is prompt.
    """

    def __init__(self) -> None:
        self.stop = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def running(self) -> bool:
        return bool(self._threads)

    def start(self, *loops: tuple[Callable[[], None], str]) -> None:
        """Start one thread per ``(target, name)``."""
        self.stop.clear()
        for target, name in loops:
            thread = threading.Thread(target=target, name=name, daemon=True)
            self._threads.append(thread)
            thread.start()

    def halt(self, timeout: float = 2.0) -> None:
        """Stop and join every loop (at most `timeout` s each); idempotent."""
        self.stop.set()
        threads, self._threads = self._threads, []
        for thread in threads:
            if thread is not threading.current_thread():
                thread.join(timeout=timeout)


class LinkedAdapter(VehicleAdapter, Generic[P, L]):
    """An `VehicleAdapter` that talks to a vehicle over a link of type `L`, configured by params `P`.

    ``Cls(params, *, clock, link)``: `params` is parsed by `params_model` into ``self._p`` (a
    `ValueError` naming the key), `link` opens the link from those params (default: the adapter's
    `_default_link`, its real transport); then `_setup` builds the adapter's own state. Nothing is
    opened before `connect`.
    """

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        *,
        clock: Clock = time.monotonic,
        link: Callable[[P], L] | None = None,
    ) -> None:
        super().__init__(params, clock=clock)
        model = cast("type[P] | None", self.params_model)
        if model is None:
            raise TypeError(f"{type(self).__name__} needs a params_model")
        self._p: P = parse_params(model, self.params, self.name)
        self._opener: Callable[[P], L] = link or self._default_link
        self._workers = Workers()
        self._setup()

    def _setup(self) -> None:
        """The adapter's own state, from ``self._p`` (no I/O): the one constructor calls it last."""

    def _default_link(self, params: P) -> L:
        """The real link for `params` (serial, UDP, radio...); an adapter without one needs ``link=``."""
        raise TypeError(f"the {self.name} adapter has no link of its own: pass link=")

    @property
    def _stop(self) -> threading.Event:
        """Set while the adapter is closed: every loop and wait of the adapter ends on it."""
        return self._workers.stop
