"""A real terminal for console tests: a detached tmux session on a private server socket."""

from __future__ import annotations

import subprocess
import uuid


class Tmux:
    """``with Tmux(cmd) as t``: ``cmd`` (a shell line) runs in a 200 x 50 terminal; ``t.keys`` types,
    ``t.screen()`` reads it. The private server is killed on exit, with whatever still runs in it."""

    def __init__(self, cmd: str, *, session: str = "test") -> None:
        self.sock = f"antalate-test-{uuid.uuid4().hex[:8]}"
        self.session = session
        self.cmd = cmd

    def __enter__(self) -> Tmux:
        subprocess.run(
            [
                "tmux",
                "-L",
                self.sock,
                "new-session",
                "-d",
                "-s",
                self.session,
                "-x",
                "200",
                "-y",
                "50",
                self.cmd,
            ],
            check=True,
        )
        return self

    def __exit__(self, *exc: object) -> None:
        subprocess.run(["tmux", "-L", self.sock, "kill-server"], capture_output=True, timeout=10)

    def _tmux(self, *args: str) -> str:
        return subprocess.run(
            ["tmux", "-L", self.sock, *args], capture_output=True, text=True, timeout=10
        ).stdout

    def keys(self, *keys: str) -> None:
        self._tmux("send-keys", "-t", self.session, *keys)

    def screen(self, history: int = 0) -> str:
        """The visible screen, and ``history`` lines above it."""
        extra = ["-S", f"-{history}"] if history else []
        return self._tmux("capture-pane", "-p", *extra, "-t", self.session)


def fly_one_sortie(term: Tmux, agent_prefix: str, agents: int) -> None:
    """At the operator console: wait for every agent in STANDBY, take off all, wait for MISSION,
    RTL all after 2 s, wait for STANDBY again (the rows whose name starts with ``agent_prefix``)."""
    import time

    from tests.harness.polling import wait_for

    def count(word: str) -> int:
        return sum(
            1
            for line in term.screen().splitlines()
            if line.lstrip("│ ").startswith(agent_prefix) and f" {word} " in line
        )

    assert wait_for(lambda: count("STANDBY") == agents, 30), term.screen()
    term.keys("T")
    assert wait_for(lambda: "TAKEOFF to ALL" in term.screen(), 5), term.screen()
    term.keys("y")
    assert wait_for(lambda: count("MISSION") == agents, 30), term.screen()
    time.sleep(2)
    term.keys("R")
    assert wait_for(lambda: "RTL to ALL" in term.screen(), 5), term.screen()
    term.keys("y")
    assert wait_for(lambda: count("STANDBY") == agents, 60), term.screen()
