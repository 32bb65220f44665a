"""`antalate demo --agents 3` in a real terminal (tmux): take off all, every agent reaches MISSION,
RTL, every agent back in STANDBY, quit, and no process is left behind."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import uuid

import pytest

from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.tmux import Tmux, fly_one_sortie

pytestmark = pytest.mark.netns


def test_demo_in_a_real_terminal(netns: NetNamespace) -> None:
    if shutil.which("tmux") is None:
        pytest.skip("tmux is not installed (Debian/Ubuntu: apt-get install tmux)")
    marker = f"demo-{uuid.uuid4().hex[:8]}"
    argv = netns.wrap([sys.executable, "-m", "antalate_lcm.cli", "demo", "--agents", "3"])
    # the marker lets us find every process the demo started, whatever its name
    cmd = f"ANTALATE_TEST_MARKER={marker} {shlex.join(argv)}; echo DEMO-EXITED-$?; sleep 60"

    with Tmux(cmd, session="demo") as term:
        fly_one_sortie(term, "sim-", 3)
        term.keys("q")
        assert wait_for(lambda: "DEMO-EXITED-0" in term.screen(), 20), term.screen()
        left = subprocess.run(
            ["pgrep", "-f", "antalate_lcm.cli demo"], capture_output=True, text=True
        ).stdout.split()
        assert not [pid for pid in left if _has_marker(pid, marker)], "the demo left processes behind"


def _has_marker(pid: str, marker: str) -> bool:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            return marker.encode() in f.read()
    except OSError:
        return False
