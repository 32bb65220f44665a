"""Private network namespaces for tests, so nothing a test sends touches the host network: the one
namespace class (`NetNamespace`) and the pair of namespaces the Tello tests need (`NetnsPair`).

A `NetNamespace` is one namespace and the processes started in it (``wrap``/``popen``/``run``; all of
them stopped by ``close()``). How it is made is its mode:

* user (``NetNamespace()``, the default): a holder process made by ``unshare -rn`` (a user namespace
  too, so it works unprivileged, and as root in CI); entered with ``nsenter -U -n``;
* root (``root=True``): ``unshare -n`` only (needs root), so what runs in it stays real root, like
  podman (tests/containers); entered with ``nsenter -n``;
* nested (``inside=other``): a network namespace made inside ``other``'s user namespace, so a process
  of ``other`` has ``CAP_NET_ADMIN`` over both and can join them with a veth pair (`NetnsPair`);
* named (``name="..."``): a namespace of ``ip netns`` (needs root), entered with ``ip netns exec``:
  the hosts, switches and routers of the LAN and WAN topologies (tests/lan/topology.py builds their
  links; the namespaces and what runs in them are these).

The user and root modes bring ``lo`` up and route multicast on it (``multicast=False`` leaves the route
out): a bus on `MCAST_URL` (ttl=0) never leaves the namespace.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any, Literal

import pytest

from tests import REPO
from tests.harness.process import child_env, stop_process

#: A bus on the multicast route every namespace here has (ttl=0: it never leaves the namespace).
MCAST_URL = "udpm://239.255.76.67:7667?ttl=0"

_LO_UP = "ip link set lo up"
_MCAST_ROUTE = "ip route add 224.0.0.0/4 dev lo"

Side = Literal["a", "b"]


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


_REASON: list[str | None] = []


def netns_reason() -> str | None:
    """``netns_unavailable()``, asked once a process (each answer costs an ``unshare``)."""
    if not _REASON:
        _REASON.append(netns_unavailable())
    return _REASON[0]


def require_netns() -> None:
    """Skip the calling test, saying why, where no private network namespace can be made."""
    reason = netns_reason()
    if reason:
        pytest.skip(f"no private network namespace: {reason}")


@contextlib.contextmanager
def private_netns(*, missing: str | None = None, **kwargs: Any) -> Iterator[NetNamespace]:
    """A `NetNamespace` (``kwargs`` are its own) for a fixture's lifetime; the test skips where none can
    be made, or first with ``missing``, the reason something else it needs is not here (the firmware)."""
    if missing:
        pytest.skip(missing)
    require_netns()
    with NetNamespace(**kwargs) as ns:
        yield ns


def run_unrouted(argv: Sequence[str], timeout: float = 60, **kw: Any) -> subprocess.CompletedProcess[str]:
    """``argv`` to its end in a bare namespace (``unshare -rn``: ``lo`` down, no multicast route), a
    host as a user may have it; its output captured as text (``kw`` are subprocess.run's)."""
    require_netns()
    done: subprocess.CompletedProcess[str] = subprocess.run(
        ["unshare", "-rn", *argv], capture_output=True, text=True, timeout=timeout, **kw
    )
    return done


def netns_pair_unavailable() -> str | None:
    """Why a veth-joined namespace pair cannot be made here, or None when it can (tests skip on it)."""
    return unavailable_because(
        "ip link add t0 type veth peer name t1", "cannot create a veth pair in a private namespace"
    )


def delete_named(name: str) -> None:
    """SIGKILL whatever still runs in the named namespace ``name``, then delete it (no error if gone)."""
    for _ in range(3):
        pids = subprocess.run(["ip", "netns", "pids", name], capture_output=True, text=True, timeout=20)
        found = [int(p) for p in pids.stdout.split() if p.isdigit()]
        if not found:
            break
        for pid in found:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.1)
    subprocess.run(["ip", "netns", "delete", name], capture_output=True, text=True, timeout=20)


class NetNamespace:
    """One private network namespace and the processes started in it; the mode is chosen by the
    arguments (module doc). Use as a context manager (or ``start()`` and ``close()``)."""

    def __init__(
        self,
        *,
        root: bool = False,
        inside: NetNamespace | None = None,
        name: str | None = None,
        multicast: bool = True,
    ) -> None:
        if sum((root, inside is not None, name is not None)) > 1:
            raise ValueError("one mode: root, inside or name")
        self.root = root
        self.inside = inside
        self.name = name
        self.multicast = multicast
        self.procs: list[subprocess.Popen[str]] = []
        self._holder: subprocess.Popen[str] | None = None
        self._files: list[IO[str]] = []

    def __enter__(self) -> NetNamespace:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"NetNamespace({self.name or self._holder and self._holder.pid!r})"

    # -- lifecycle -------------------------------------------------------------------------------

    def start(self) -> NetNamespace:
        setup = f"{_LO_UP} && {_MCAST_ROUTE}" if self.multicast else _LO_UP
        if self.name is not None:
            for argv in (["ip", "netns", "add", self.name], ["ip", "-n", self.name, *_LO_UP.split()[1:]]):
                done = subprocess.run(argv, capture_output=True, text=True, timeout=20)
                if done.returncode != 0:
                    raise RuntimeError(f"{' '.join(argv)} failed: {done.stderr.strip()}")
            return self
        script = f"{setup} && echo ready && exec cat"
        if self.inside is not None:
            argv = self.inside.wrap(["unshare", "-n", "sh", "-c", script])
        else:
            argv = ["unshare", "-n" if self.root else "-rn", "sh", "-c", script]
        # the holder reads a pipe from this process, so it exits with it, even after a SIGKILL
        self._holder = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        assert self._holder.stdout is not None
        if self._holder.stdout.readline().strip() != "ready":
            err = self._holder.stderr.read() if self._holder.stderr else ""
            self.close()
            raise RuntimeError(f"network namespace set-up failed ({' '.join(argv)}): {err.strip()}")
        return self

    def stop(self, timeout: float = 5.0) -> dict[int, int | None]:
        """Stop every process started here (SIGTERM, then SIGKILL the stubborn), newest first; the
        namespace stays. Returns each one's exit code by pid."""
        codes = {}
        for proc in reversed(self.procs):
            codes[proc.pid] = stop_process(proc, timeout)
        self.procs.clear()
        for f in self._files:
            f.close()
        self._files.clear()
        return codes

    def close(self) -> None:
        """Stop every process started here, then end the namespace."""
        self.stop()
        if self._holder is not None:
            stop_process(self._holder)
            self._holder = None
        if self.name is not None:
            delete_named(self.name)

    # -- running things inside -------------------------------------------------------------------

    @property
    def pid(self) -> int:
        """The holder's pid (not for a named namespace, which has none)."""
        assert self._holder is not None, "a named or unstarted namespace has no holder"
        return self._holder.pid

    def wrap(self, argv: Sequence[str]) -> list[str]:
        """The command line that runs ``argv`` inside this namespace."""
        if self.name is not None:
            return ["ip", "netns", "exec", self.name, *argv]
        if self.root:
            return ["nsenter", "-t", str(self.pid), "-n", "--", *argv]
        return ["nsenter", "-t", str(self.pid), "-U", "-n", "--preserve-credentials", "--", *argv]

    def popen(
        self,
        argv: Sequence[str],
        *,
        outside: Sequence[str] = (),
        log: Path | None = None,
        extra_env: Mapping[str, str] | None = None,
        **kwargs: Any,
    ) -> subprocess.Popen[str]:
        """Start ``argv`` inside, in a process group of its own (``close()`` stops it and all it
        started), the checkout importable, in the checkout. ``kwargs`` are Popen's; ``log``: a file
        for stdout and stderr; ``extra_env``: added to the environment; ``outside``: a command run on
        the host that runs the way in (``nice -n -10``: a priority is the host's, which the
        namespace's own root cannot raise)."""
        kwargs.setdefault("env", _env(extra_env))
        kwargs.setdefault("text", True)
        kwargs.setdefault("start_new_session", True)
        kwargs.setdefault("cwd", str(REPO))
        if log is not None:
            out = open(log, "w")  # noqa: SIM115 - closed by stop()
            self._files.append(out)
            kwargs.setdefault("stdout", out)
            kwargs.setdefault("stderr", subprocess.STDOUT)
        proc: subprocess.Popen[str] = subprocess.Popen([*outside, *self.wrap(argv)], **kwargs)
        self.procs.append(proc)
        return proc

    def run(
        self,
        argv: Sequence[str],
        timeout: float = 60,
        *,
        extra_env: Mapping[str, str] | None = None,
        **kwargs: Any,
    ) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` inside to completion, stdout and stderr captured as text."""
        kwargs.setdefault("env", _env(extra_env))
        kwargs.setdefault("cwd", str(REPO))
        done: subprocess.CompletedProcess[str] = subprocess.run(
            self.wrap(argv), timeout=timeout, capture_output=True, text=True, **kwargs
        )
        return done

    def python(self, *args: str, **kwargs: Any) -> subprocess.Popen[str]:
        return self.popen([sys.executable, *args], **kwargs)

    def antalate(self, *args: str, **kwargs: Any) -> subprocess.Popen[str]:
        return self.python("-m", "antalate_lcm.cli", *args, **kwargs)

    def peer(self, module: str, *args: str, **kwargs: Any) -> subprocess.Popen[str]:
        """``python -m module ARGS`` inside, stdin, stdout and stderr piped: a JSON-lines peer of the
        test (tests.harness.jsonl), such as the LCM probe or an attacker."""
        pipes = {"stdin": subprocess.PIPE, "stdout": subprocess.PIPE, "stderr": subprocess.PIPE}
        return self.python("-m", module, *args, **pipes, **kwargs)

    def socket(self, kind: Literal["udp", "tcp"], bind: tuple[str, int]) -> socket.socket:
        """A UDP socket bound to ``bind`` (or a listening TCP one) made inside, usable from this
        process: a socket keeps the namespace it was created in. tests/children/bind_socket.py binds
        it there and hands the descriptor back over a Unix socket (``SCM_RIGHTS``)."""
        mine, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            argv = [sys.executable, "-m", "tests.children.bind_socket", kind, bind[0], str(bind[1])]
            done = self.run([*argv, str(theirs.fileno())], timeout=30, pass_fds=[theirs.fileno()])
            theirs.close()
            if done.returncode != 0:
                raise RuntimeError(f"cannot bind {kind} {bind} in {self!r}: {done.stderr.strip()}")
            _msg, fds, _flags, _addr = socket.recv_fds(mine, 16, 1)
            return socket.socket(fileno=fds[0])
        finally:
            theirs.close()
            mine.close()


def _env(extra: Mapping[str, str] | None) -> dict[str, str]:
    env = child_env()
    if extra:
        env.update(extra)
    return env


class NetnsPair:
    """Two namespaces joined by a veth pair: how tests run djitellopy against the emulator.

    Why two: djitellopy 2.5 binds UDP 8889 (commands) and 8890 (state) on *all* addresses, once per
    process, without ``SO_REUSEADDR``. A Tello emulator must also receive on port 8889, and Linux refuses
    to bind ``127.0.0.2:8889`` while ``0.0.0.0:8889`` is bound in the same namespace (``EADDRINUSE``).
    So the client and the emulator live in different namespaces, connected by a link.

    Side ``"a"`` (the drone side) is a user-mode `NetNamespace`, side ``"b"`` (the ground side) one
    nested in it, so a process in a can create the veth pair between them (no host interface is touched,
    and it works unprivileged). ``veth_a`` in a carries ``addr_a`` (default ``192.168.10.1``, the real
    Tello's address, so ``Tello()`` needs no host argument), ``veth_b`` in b carries ``addr_b``.

    The emulator usually runs *in the test process*, so tests can read its state and inject faults with
    plain method calls, on a socket made in side a (``udp_socket``)::

        with NetnsPair() as net:
            sock = net.udp_socket("a", (net.addr_a, 8889))
            with TelloEmulator(sock=sock) as tello:
                result = net.run("b", [sys.executable, "-m", "tests.children.djitellopy_flight"], timeout=30)
                assert tello.snapshot().z > 0.5 ...

    Extra addresses (``extra_addrs_a``) let several emulators (a swarm of Tellos) share side a.
    Use as a context manager: everything started here is stopped on the way out.
    """

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
        a = NetNamespace(multicast=False)
        self.sides: dict[Side, NetNamespace] = {"a": a, "b": NetNamespace(inside=a, multicast=False)}

    def start(self) -> NetnsPair:
        try:
            self.sides["a"].start()
            self.sides["b"].start()
            self._check("a", f"ip link add veth_a type veth peer name veth_b netns {self.pid('b')}")
            sides: tuple[tuple[Side, str, str], ...] = (
                ("a", "veth_a", self.addr_a),
                ("b", "veth_b", self.addr_b),
            )
            for side, dev, addr in sides:
                script = [f"ip addr add {addr}/{self.prefix_len} dev {dev}"]
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
        """Stop every process started on either side, then the sides, b first (the veth goes with them)."""
        for ns in self.sides.values():
            ns.stop()
        self.sides["b"].close()
        self.sides["a"].close()

    def __enter__(self) -> NetnsPair:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pid(self, side: Side) -> int:
        return self.sides[side].pid

    def wrap(self, side: Side, argv: Sequence[str]) -> list[str]:
        """The command line that runs ``argv`` inside ``side``."""
        return self.sides[side].wrap(argv)

    def popen(self, side: Side, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[str]:
        """Start ``argv`` inside ``side`` (`NetNamespace.popen`); it is stopped by ``close()``."""
        return self.sides[side].popen(argv, **kwargs)

    def run(
        self, side: Side, argv: Sequence[str], timeout: float = 60, **kwargs: Any
    ) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` inside ``side`` to completion (`NetNamespace.run`)."""
        return self.sides[side].run(argv, timeout, **kwargs)

    def udp_socket(self, side: Side, bind: tuple[str, int]) -> socket.socket:
        """A UDP socket bound to ``bind`` inside ``side``, usable from this process."""
        return self.sides[side].socket("udp", bind)

    def tcp_listener(self, side: Side, bind: tuple[str, int]) -> socket.socket:
        """A listening TCP socket bound to ``bind`` inside ``side``, usable from this process."""
        return self.sides[side].socket("tcp", bind)

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
