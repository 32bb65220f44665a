"""A child process that reports what happens as JSON lines, read into a timeline tests wait on in order.

The end-to-end tests of the Tello and the Crazyflie run an agent (and its emulator) in a child process
that prints one JSON event a line (``{"kind": "mc", "state": "MISSION", ...}``) and takes commands on
stdin. `EventTimeline` reads those events on a thread as they come; `wait` follows them in order, so
``wait("hlc", state="READY")`` after a take-off finds the READY of the landing, not the one at
start-up. The child's end is an event too (``{"kind": "exit"}``): a wait fails at once, with the
timeline and the child's log, when the process is gone.
"""

from __future__ import annotations

import json
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

Event = dict[str, Any]


class EventTimeline:
    """The events of `proc` (stdout, JSON lines), its log at `log_path`; `noise` is left out of `timeline`."""

    def __init__(self, proc: subprocess.Popen[str], log_path: Path, *, noise: str = "") -> None:
        self.proc = proc
        self.log_path = log_path
        self.noise = noise
        self.events: list[Event] = []
        self._cursor = 0
        self._cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cond:
                self.events.append(json.loads(line))
                self._cond.notify_all()
        with self._cond:
            self.events.append({"kind": "exit"})
            self._cond.notify_all()

    def wait(
        self,
        kind: str,
        timeout: float,
        test: Callable[[Event], bool] | None = None,
        *,
        poll: Callable[[], None] | None = None,
        **where: Any,
    ) -> Event:
        """The next event of `kind` matching `where` (and `test`) after the one the previous wait returned.

        `poll` is called between looks (a test watching its emulator meanwhile).
        """
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for i in range(self._cursor, len(self.events)):
                    e = self.events[i]
                    if (
                        e["kind"] == kind
                        and all(e.get(k) == v for k, v in where.items())
                        and (test is None or test(e))
                    ):
                        self._cursor = i + 1
                        return e
                left = deadline - time.monotonic()
                if left <= 0 or self.events[-1:] == [{"kind": "exit"}]:
                    raise AssertionError(
                        f"no {kind} {where} within {timeout} s; timeline:\n{self.timeline()}"
                        f"\nlog:\n{self.log_tail()}"
                    )
                self._cond.wait(min(left, 0.05))
                if poll is not None:
                    poll()

    def mark(self) -> int:
        """Where the next wait starts looking, to come back to with rewind."""
        with self._cond:
            return self._cursor

    def rewind(self, mark: int) -> None:
        with self._cond:
            self._cursor = mark

    def last(self, kind: str, **where: Any) -> Event:
        with self._cond:
            return next(
                e
                for e in reversed(self.events)
                if e["kind"] == kind and all(e.get(k) == v for k, v in where.items())
            )

    def all(self, kind: str) -> list[Event]:
        with self._cond:
            return [e for e in self.events if e["kind"] == kind]

    def states(self, kind: str) -> list[str]:
        """The ``state`` of every event of `kind` so far (a machine's transitions, in order)."""
        return [e["state"] for e in self.all(kind)]

    def errors(self) -> list[Event]:
        return self.all("error")

    def timeline(self) -> str:
        with self._cond:
            return "\n".join(json.dumps(e) for e in self.events if e["kind"] != self.noise)

    def log_tail(self, n: int = 40) -> str:
        return "\n".join(self.log_path.read_text().splitlines()[-n:])

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def stop(self, timeout: float = 15.0) -> None:
        """Ask the child to stop (``stop`` on stdin); killed when it has not ended in `timeout` s."""
        if self.proc.poll() is None and self.proc.stdin is not None:
            try:
                self.send("stop")
                self.proc.wait(timeout)
            except (BrokenPipeError, subprocess.TimeoutExpired):
                self.proc.kill()
