"""Two private network namespaces joined by a veth pair: how tests run djitellopy against the emulator.

Why two namespaces: djitellopy 2.5 binds UDP 8889 (commands) and 8890 (state) on *all* addresses, once
per process, without ``SO_REUSEADDR``. A Tello emulator must also receive on port 8889, and Linux refuses
to bind ``127.0.0.2:8889`` while ``0.0.0.0:8889`` is bound in the same namespace (``EADDRINUSE``). So the
client and the emulator must live in different network namespaces, connected by a link.

The arrangement (no host interface is touched, and it also works unprivileged):

* side ``"a"`` (the drone side): a holder process made by ``unshare -rn`` (new user + network namespace);
* side ``"b"`` (the ground side): a holder made *inside* a's user namespace with ``unshare -n``, so the
  process in a has ``CAP_NET_ADMIN`` over both namespaces and can create a veth pair between them;
* ``veth_a`` in a carries ``addr_a`` (default ``192.168.10.1``, the real Tello's address, so
  ``Tello()`` needs no host argument), ``veth_b`` in b carries ``addr_b`` (``192.168.10.2``).

Commands run inside either side through ``nsenter`` (``popen``/``run``). The emulator itself usually
runs *in the test process*, so tests can read its state and inject faults with plain method calls: its
UDP socket is created inside side a by a short-lived helper and handed back over a Unix socket
(``SCM_RIGHTS``). A socket keeps the namespace it was created in, so the emulator thread in the test
process sends and receives on side a's network::

    with NetnsPair() as net:
        sock = net.udp_socket("a", (net.addr_a, 8889))
        with TelloEmulator(sock=sock) as tello:
            result = net.run("b", [sys.executable, "-m", "tests.children.djitellopy_flight"], timeout=30)
            assert tello.snapshot().z > 0.5 ...

Extra addresses (``extra_addrs_a``) let several emulators (a swarm of Tellos) share side a. Everything
started here is stopped by ``close()`` (also on exceptions, through the context manager); the holders
also exit by themselves when the test process dies, because they block reading a pipe from it.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any, Literal

from tests import REPO
from tests.harness.netns import unavailable_because
from tests.harness.process import stop_process

Side = Literal["a", "b"]

_READY = "echo ready && exec cat"


def netns_pair_unavailable() -> str | None:
    """Why a veth-joined namespace pair cannot be made here, or None when it can (tests skip on it)."""
    return unavailable_because(
        "ip link add t0 type veth peer name t1", "cannot create a veth pair in a private namespace"
    )


class NetnsPair:
    """Namespaces ``a`` and ``b`` joined by ``veth_a``/``veth_b`` on one subnet. Use as a context manager."""

    def __init__(
        self,
        addr_a: str = "192.168.10.1",
        addr_b: str = "192.168.10.2",
        prefix_len: int = 24,
        extra_addrs_a: Sequence[str] = (),
        extra_addrs_b: Sequence[str] = (),
    ) -> None:
        self.addr_a = addr_a
        self.addr_b = addr_b
        self.prefix_len = prefix_len
        self.extra_addrs = {"a": list(extra_addrs_a), "b": list(extra_addrs_b)}
        self._holders: dict[str, subprocess.Popen[str]] = {}
        self._children: list[subprocess.Popen[str]] = []

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self) -> NetnsPair:
        try:
            self._holders["a"] = self._spawn_holder(["unshare", "-rn", "sh", "-c", _READY])
            self._holders["b"] = self._spawn_holder(self.wrap("a", ["unshare", "-n", "sh", "-c", _READY]))
            self._check(
                "a",
                f"ip link set lo up && ip link add veth_a type veth peer name veth_b netns {self.pid('b')}",
            )
            sides: tuple[tuple[Side, str, str], ...] = (
                ("a", "veth_a", self.addr_a),
                ("b", "veth_b", self.addr_b),
            )
            for side, dev, addr in sides:
                script = [f"ip link set lo up && ip addr add {addr}/{self.prefix_len} dev {dev}"]
                script += [
                    f"ip addr add {extra}/{self.prefix_len} dev {dev}" for extra in self.extra_addrs[side]
                ]
                script.append(f"ip link set {dev} up")
                self._check(side, " && ".join(script))
            self._wait_link_up()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop every process started here, then the holders (which takes the namespaces and veth down)."""
        for proc in self._children:
            stop_process(proc)
        self._children.clear()
        for side in ("b", "a"):
            holder = self._holders.pop(side, None)
            if holder is not None:
                stop_process(holder)

    def __enter__(self) -> NetnsPair:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- running things inside -------------------------------------------------------------------

    def pid(self, side: Side) -> int:
        return self._holders[side].pid

    def wrap(self, side: Side, argv: Sequence[str]) -> list[str]:
        """The command line that runs ``argv`` inside ``side``."""
        return ["nsenter", "-t", str(self.pid(side)), "-U", "-n", "--preserve-credentials", "--", *argv]

    def popen(self, side: Side, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[str]:
        """Start ``argv`` inside ``side``; it is stopped by ``close()``. The repo is on PYTHONPATH.
        ``kwargs`` are Popen's, plus ``extra_env`` (added to the environment)."""
        kwargs.setdefault("env", _env(kwargs.pop("extra_env", None)))
        kwargs.setdefault("text", True)
        kwargs.setdefault("start_new_session", True)
        kwargs.setdefault("cwd", str(REPO))
        proc: subprocess.Popen[str] = subprocess.Popen(self.wrap(side, argv), **kwargs)
        self._children.append(proc)
        return proc

    def run(
        self, side: Side, argv: Sequence[str], timeout: float = 60, **kwargs: Any
    ) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` inside ``side`` to completion (stdout/stderr captured as text)."""
        kwargs.setdefault("env", _env(kwargs.pop("extra_env", None)))
        kwargs.setdefault("cwd", str(REPO))
        done: subprocess.CompletedProcess[str] = subprocess.run(
            self.wrap(side, argv), timeout=timeout, capture_output=True, text=True, **kwargs
        )
        return done

    def udp_socket(self, side: Side, bind: tuple[str, int]) -> socket.socket:
        """A UDP socket bound to ``bind`` inside ``side``, usable from this process (see module doc)."""
        return self._socket(side, "udp", bind)

    def tcp_listener(self, side: Side, bind: tuple[str, int]) -> socket.socket:
        """A listening TCP socket bound to ``bind`` inside ``side``, usable from this process."""
        return self._socket(side, "tcp", bind)

    # -- internals -------------------------------------------------------------------------------

    def _socket(self, side: Side, kind: str, bind: tuple[str, int]) -> socket.socket:
        mine, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            # tests/children/bind_socket.py binds it there and hands the descriptor back
            argv = [
                sys.executable,
                "-m",
                "tests.children.bind_socket",
                kind,
                bind[0],
                str(bind[1]),
                str(theirs.fileno()),
            ]
            done = subprocess.run(
                self.wrap(side, argv),
                pass_fds=[theirs.fileno()],
                capture_output=True,
                text=True,
                timeout=30,
                env=_env(),
                cwd=str(REPO),
            )
            theirs.close()
            if done.returncode != 0:
                raise RuntimeError(f"cannot bind {kind} {bind} in namespace {side}: {done.stderr.strip()}")
            _msg, fds, _flags, _addr = socket.recv_fds(mine, 16, 1)
            return socket.socket(fileno=fds[0])
        finally:
            theirs.close()
            mine.close()

    def _spawn_holder(self, argv: list[str]) -> subprocess.Popen[str]:
        holder = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        assert holder.stdout is not None
        if holder.stdout.readline().strip() != "ready":
            err = holder.stderr.read() if holder.stderr else ""
            stop_process(holder)
            raise RuntimeError(f"cannot create a network namespace ({' '.join(argv)}): {err.strip()}")
        return holder

    def _wait_link_up(self, timeout: float = 5.0) -> None:
        """Carrier takes a moment after ``ip link set up``; packets sent before it are lost."""
        deadline = time.monotonic() + timeout
        sides: tuple[tuple[Side, str], ...] = (("a", "veth_a"), ("b", "veth_b"))
        for side, dev in sides:
            while (
                "state UP" not in self.run(side, ["ip", "-o", "link", "show", "dev", dev], timeout=10).stdout
            ):
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{dev} in namespace {side} did not come up")
                time.sleep(0.01)

    def _check(self, side: Side, script: str) -> None:
        done = self.run(side, ["sh", "-c", script], timeout=30)
        if done.returncode != 0:
            raise RuntimeError(f"namespace {side} set-up failed ({script}): {done.stderr.strip()}")


def _env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    if extra:
        env.update(extra)
    return env
