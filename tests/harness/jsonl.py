"""A child process driven by JSON lines: one request a line on stdin, one reply a line on stdout.

Tests use it for peers that must live inside a network namespace (the LCM probe, the LAN operator,
the attackers and witnesses of tests/security): `JsonLinesProcess` is the test's side, `serve` the
child's.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from typing import Any


def serve(handle: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
    """The child's side: a ready line, then ``handle``'s reply to each request line until stdin ends.
    A request that raises is answered with the error (the test reads it) and the child serves on."""
    print(json.dumps({"ok": True, "ready": True}), flush=True)
    for line in sys.stdin:
        try:
            reply = handle(json.loads(line))
        except Exception as exc:  # noqa: BLE001 - reported to the test, which judges it
            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(reply), flush=True)


class JsonLinesProcess:
    def __init__(self, proc: subprocess.Popen[str], what: str) -> None:
        self.proc = proc
        self.what = what
        first = self._read()
        assert first.get("ready"), first

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise RuntimeError(f"{self.what} exited: {err[-2000:]}")
        reply: dict[str, Any] = json.loads(line)
        return reply

    def call(self, **req: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self._read()
