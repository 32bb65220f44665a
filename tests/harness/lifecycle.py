"""The lifecycle of a test's multi-part fixture (a LAN topology, a swarm on it): started by ``with``,
and a start that fails part-way closes what it had started before the error goes on, so nothing of a
half-built set-up outlives the test."""

from __future__ import annotations

from typing import TypeVar

T = TypeVar("T", bound="Started")


class Started:
    def _start(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self: T) -> T:
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
