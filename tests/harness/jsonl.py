"""A child process driven by JSON lines: one request a line on stdin, one reply a line on stdout.

Tests use it for peers that must live inside a network namespace (the LCM probe, the LAN operator).
"""

from __future__ import annotations

import json
import subprocess
from typing import Any


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
