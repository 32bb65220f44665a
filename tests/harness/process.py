"""Child processes of the tests: the environment they start with, and stopping them with everything they
started (their whole process group), so nothing outlives a test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from tests import REPO


def child_env() -> dict[str, str]:
    """The environment of a test's child process: this checkout importable, output unbuffered (so
    a log read after a crash holds everything the child printed)."""
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


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
