"""Child processes of the tests: the ``antalate`` command as a user runs it, the environment children
start with, and stopping them with everything they started (their whole process group), so nothing
outlives a test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from tests import REPO


def child_env() -> dict[str, str]:
    """The environment of a test's child process: this checkout importable, output unbuffered (so
    a log read after a crash holds everything the child printed)."""
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def antalate_argv(*args: str) -> list[str]:
    """The ``antalate`` command line of this checkout's interpreter (a venv need not be on PATH)."""
    return [sys.executable, "-m", "antalate_lcm.cli", *args]


def run_antalate(*args: str, timeout: float | None = 60, **kw: Any) -> subprocess.CompletedProcess[str]:
    """``antalate ARGS`` to its end, its output captured as text, in ``child_env()`` unless ``kw``
    (subprocess.run's) says otherwise."""
    kw.setdefault("env", child_env())
    done: subprocess.CompletedProcess[str] = subprocess.run(
        antalate_argv(*args), capture_output=True, text=True, timeout=timeout, **kw
    )
    return done


class OutputLines:
    """The lines a child writes to one of its pipes, read on a thread as they come, so a silent child
    never blocks the test and a test can wait for the line that says the child is ready."""

    def __init__(self, stream: IO[str]) -> None:
        self.lines: list[str] = []
        self.ended = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        try:
            for line in stream:
                with self._cond:
                    self.lines.append(line.rstrip())
                    self._cond.notify_all()
        except (ValueError, OSError):  # stop_process closed the pipe under the reader
            pass
        with self._cond:
            self.ended = True
            self._cond.notify_all()

    def wait(self, done: Callable[[str], bool], timeout: float) -> str | None:
        """The first line so far or within ``timeout`` s for which ``done`` holds; None when the
        child's output ends (it is gone) or time is up without one."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                hit = next((line for line in self.lines if done(line)), None)
                left = deadline - time.monotonic()
                if hit is not None or self.ended or left <= 0:
                    return hit
                self._cond.wait(left)

    def join(self, timeout: float = 5.0) -> None:
        self._thread.join(timeout)

    def text(self) -> str:
        with self._cond:
            return "\n".join(self.lines)


def stop_process(proc: subprocess.Popen[str], timeout: float = 5.0) -> int | None:
    """SIGTERM the process group, then SIGKILL if it does not exit: nothing is left behind."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except (ProcessLookupError, PermissionError):
            proc.terminate()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                proc.kill()
            proc.wait(timeout)
    _end_group(proc.pid, timeout)
    for stream in (proc.stdout, proc.stderr, proc.stdin):
        if stream is not None:
            stream.close()
    return proc.returncode


def _end_group(pgid: int, timeout: float) -> None:
    """What the leader left of its group (xvfb-run signals Xvfb on its way out and never waits for
    it): SIGTERM, then SIGKILL what is still there after ``timeout``."""
    if not group_members(pgid):
        return
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pgid, sig)
        except (ProcessLookupError, PermissionError):
            return
        deadline = time.monotonic() + timeout
        while group_members(pgid) and time.monotonic() < deadline:
            time.sleep(0.02)
        if not group_members(pgid):
            return


def group_members(pgid: int) -> list[str]:
    """The live processes of a process group, as "pid state cmdline" (zombies, which only wait for
    their reaper, are not counted)."""
    members = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            command = cmdline.replace(b"\0", b" ").decode(errors="replace").strip()
            members.append(f"{entry.name} {fields[0]} {command}")
    return members
