"""`antalate demo --agents 3` in a real terminal (tmux): take off all, every agent reaches MISSION,
RTL, every agent back in STANDBY, quit, and no process is left behind."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import time
import uuid

import pytest

from tests.netns import NetNamespace
from tests.polling import wait_for

pytestmark = pytest.mark.netns


def test_demo_in_a_real_terminal(netns: NetNamespace) -> None:
    if shutil.which("tmux") is None:
        pytest.skip("tmux is not installed (Debian/Ubuntu: apt-get install tmux)")
    sock = f"antalate-test-{uuid.uuid4().hex[:8]}"
    marker = f"demo-{uuid.uuid4().hex[:8]}"
    argv = netns.wrap([sys.executable, "-m", "antalate_lcm.cli", "demo", "--agents", "3"])
    # the marker lets us find every process the demo started, whatever its name
    cmd = f"ANTALATE_TEST_MARKER={marker} {shlex.join(argv)}; echo DEMO-EXITED-$?; sleep 60"

    def tmux(*args: str) -> str:
        return subprocess.run(["tmux", "-L", sock, *args], capture_output=True, text=True, timeout=10).stdout

    def screen() -> str:
        return tmux("capture-pane", "-p", "-t", "demo")

    def count(word: str) -> int:
        return sum(
            1
            for line in screen().splitlines()
            if line.lstrip("│ ").startswith("sim-") and f" {word} " in line
        )

    subprocess.run(
        ["tmux", "-L", sock, "new-session", "-d", "-s", "demo", "-x", "200", "-y", "50", cmd], check=True
    )
    try:
        assert wait_for(lambda: count("STANDBY") == 3, 30), screen()
        tmux("send-keys", "-t", "demo", "T")
        assert wait_for(lambda: "TAKEOFF to ALL" in screen(), 5), screen()
        tmux("send-keys", "-t", "demo", "y")
        assert wait_for(lambda: count("MISSION") == 3, 30), screen()
        time.sleep(2)
        tmux("send-keys", "-t", "demo", "R")
        assert wait_for(lambda: "RTL to ALL" in screen(), 5), screen()
        tmux("send-keys", "-t", "demo", "y")
        assert wait_for(lambda: count("STANDBY") == 3, 60), screen()
        tmux("send-keys", "-t", "demo", "q")
        assert wait_for(lambda: "DEMO-EXITED-0" in screen(), 20), screen()
        left = subprocess.run(
            ["pgrep", "-f", "antalate_lcm.cli demo"], capture_output=True, text=True
        ).stdout.split()
        assert not [pid for pid in left if _has_marker(pid, marker)], "the demo left processes behind"
    finally:
        subprocess.run(["tmux", "-L", sock, "kill-server"], capture_output=True, timeout=10)


def _has_marker(pid: str, marker: str) -> bool:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            return marker.encode() in f.read()
    except OSError:
        return False
