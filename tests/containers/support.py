"""Podman with its own storage, and a network namespace for containers on the host network.

Everything podman keeps for these tests lives under one folder (``--root``, ``--runroot``,
``--tmpdir``), so the host's images and containers are never touched and the folder goes with the
test. ``--network host`` puts a container in the network namespace of the podman that started it:
started through :class:`RootNetns` (``unshare -n``, root), that is a private namespace with only
``lo`` and the multicast route, never the host's network.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from tests import REPO
from tests.netns import stop_process

_SETUP = "ip link set lo up && ip route add 224.0.0.0/4 dev lo && echo ready && exec sleep 100000"


def load_build_module() -> ModuleType:
    """containers/build_image.py (a script, not a package) as a module."""
    spec = importlib.util.spec_from_file_location(
        "antalate_build_image", REPO / "containers" / "build_image.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def podman_unavailable() -> str | None:
    if os.geteuid() != 0:
        return "the container tests run podman as root (CI does)"
    for tool, package in (
        ("podman", "podman"),
        ("mmdebstrap", "mmdebstrap"),
        ("unshare", "util-linux"),
        ("nsenter", "util-linux"),
        ("ip", "iproute2"),
    ):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian: apt-get install {package})"
    probe = subprocess.run(["unshare", "-n", "sh", "-c", "ip link set lo up"], capture_output=True, text=True)
    if probe.returncode != 0:
        return f"cannot create a network namespace (unshare -n): {probe.stderr.strip()}"
    return None


class RootNetns:
    """A network namespace (no user namespace: podman must stay real root) with multicast on lo."""

    def __init__(self) -> None:
        self.holder = subprocess.Popen(
            ["unshare", "-n", "sh", "-c", _SETUP],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        assert self.holder.stdout is not None
        if self.holder.stdout.readline().strip() != "ready":
            err = self.holder.stderr.read() if self.holder.stderr else ""
            stop_process(self.holder)
            raise RuntimeError(f"network namespace set-up failed: {err.strip()}")
        self.children: list[subprocess.Popen[str]] = []

    def wrap(self, argv: Sequence[str]) -> list[str]:
        return ["nsenter", "-t", str(self.holder.pid), "-n", "--", *argv]

    def popen(self, argv: Sequence[str], **kwargs: object) -> subprocess.Popen[str]:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
        kwargs.setdefault("env", env)
        kwargs.setdefault("text", True)
        kwargs.setdefault("start_new_session", True)
        proc: subprocess.Popen[str] = subprocess.Popen(self.wrap(argv), **kwargs)  # type: ignore[call-overload]
        self.children.append(proc)
        return proc

    def close(self) -> None:
        for proc in self.children:
            stop_process(proc)
        stop_process(self.holder)


class Podman:
    """``podman`` with storage under ``root`` and no systemd (cgroupfs, events to a file)."""

    def __init__(self, root: Path, driver: str, netns: RootNetns | None = None) -> None:
        self.root = root
        self.driver = driver
        self.netns = netns
        for sub in ("storage", "run", "tmp"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        self.opts = [
            "--root",
            str(root / "storage"),
            "--runroot",
            str(root / "run"),
            "--tmpdir",
            str(root / "tmp"),
            "--storage-driver",
            driver,
            "--cgroup-manager",
            "cgroupfs",
            "--events-backend",
            "file",
        ]
        self.run_flags: list[str] = []

    def env(self) -> dict[str, str]:
        return dict(os.environ, TMPDIR=str(self.root / "tmp"))

    def command(self, *args: str) -> list[str]:
        argv = ["podman", *self.opts, *args]
        return self.netns.wrap(argv) if self.netns is not None else argv

    def __call__(self, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            self.command(*args), capture_output=True, text=True, timeout=timeout, env=self.env()
        )

    def in_netns(self, netns: RootNetns) -> Podman:
        other = Podman(self.root, self.driver, netns)
        other.run_flags = list(self.run_flags)
        return other

    def reset(self) -> None:
        self("rm", "--all", "--force", timeout=120)
        self("system", "reset", "--force", timeout=120)
