"""Private network namespaces for tests, so multicast never touches the host network.

``NetNamespace`` starts a holder process with ``unshare -rn`` (works unprivileged, and as root in
CI), brings ``lo`` up and adds the multicast route, then runs commands inside it with ``nsenter``.
Its root mode (``NetNamespace(root=True)``: ``unshare -n``, no user namespace) is for what must stay
real root inside, like podman (tests/containers).

The other topologies are built differently and live apart: two namespaces joined by a veth pair
(tests/emulators/netns_pair.py) and the named namespaces on bridges of the LAN and WAN tests
(tests/lan/topology.py).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Sequence
from typing import Any

from tests.harness.process import child_env, stop_process

#: A bus on the multicast route every namespace here has (ttl=0: it never leaves the namespace).
MCAST_URL = "udpm://239.255.76.67:7667?ttl=0"

_SETUP = "ip link set lo up && ip route add 224.0.0.0/4 dev lo && echo ready && exec sleep 100000"


def unavailable_because(script: str, failure: str) -> str | None:
    """Why ``script`` cannot run in a fresh private namespace here (a tool missing, or ``failure`` and
    what the kernel said), or None when it can: the reason a test skips on."""
    for tool in ("unshare", "nsenter", "ip"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian/Ubuntu: apt-get install util-linux iproute2)"
    probe = subprocess.run(["unshare", "-rn", "sh", "-c", script], capture_output=True, text=True)
    if probe.returncode != 0:
        return f"{failure}: {probe.stderr.strip()}"
    return None


def netns_unavailable() -> str | None:
    """The reason private namespaces cannot be made here, or None when they can."""
    return unavailable_because("ip link set lo up", "cannot create a network namespace (unshare -rn)")


class NetNamespace:
    """A private network namespace with multicast routed on ``lo``. Use as a context manager (or
    ``start()`` and ``close()``).

    ``root=False`` (the default): a user namespace too (``unshare -rn``), which works unprivileged.
    ``root=True``: a network namespace only (``unshare -n``, needs root), so what runs in it stays
    real root; its holder leads a session of its own."""

    def __init__(self, *, root: bool = False) -> None:
        self.root = root
        self._holder: subprocess.Popen[str] | None = None
        self._children: list[subprocess.Popen[str]] = []

    def __enter__(self) -> NetNamespace:
        return self.start()

    def start(self) -> NetNamespace:
        unshare = ["unshare", "-n"] if self.root else ["unshare", "-rn"]
        self._holder = subprocess.Popen(
            [*unshare, "sh", "-c", _SETUP],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=self.root,
        )
        assert self._holder.stdout is not None
        line = self._holder.stdout.readline().strip()
        if line != "ready":
            err = self._holder.stderr.read() if self._holder.stderr else ""
            self.close()
            raise RuntimeError(f"network namespace set-up failed: {err.strip()}")
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def pid(self) -> int:
        assert self._holder is not None
        return self._holder.pid

    def wrap(self, argv: Sequence[str]) -> list[str]:
        """The command line that runs ``argv`` inside this namespace."""
        if self.root:
            return ["nsenter", "-t", str(self.pid), "-n", "--", *argv]
        return ["nsenter", "-t", str(self.pid), "-U", "-n", "--preserve-credentials", "--", *argv]

    def popen(
        self, argv: Sequence[str], *, outside: Sequence[str] = (), **kwargs: Any
    ) -> subprocess.Popen[str]:
        """``kwargs`` are Popen's (any of them, as a caller would pass them to Popen itself);
        ``outside``: a command run on the host that runs the way in (``nice -n -10``: a priority is
        the host's, which the namespace's own root cannot raise)."""
        kwargs.setdefault("env", child_env())
        kwargs.setdefault("text", True)
        kwargs.setdefault("start_new_session", True)
        proc: subprocess.Popen[str] = subprocess.Popen([*outside, *self.wrap(argv)], **kwargs)
        self._children.append(proc)
        return proc

    def run(
        self, argv: Sequence[str], timeout: float = 60, **kwargs: Any
    ) -> subprocess.CompletedProcess[str]:
        done: subprocess.CompletedProcess[str] = subprocess.run(
            self.wrap(argv), timeout=timeout, capture_output=True, text=True, **kwargs
        )
        return done

    def python(self, *args: str, **kwargs: Any) -> subprocess.Popen[str]:
        return self.popen([sys.executable, *args], **kwargs)

    def antalate(self, *args: str, **kwargs: Any) -> subprocess.Popen[str]:
        return self.python("-m", "antalate_lcm.cli", *args, **kwargs)

    def close(self) -> None:
        for proc in self._children:
            stop_process(proc)
        self._children.clear()
        if self._holder is not None:
            stop_process(self._holder)
            self._holder = None
