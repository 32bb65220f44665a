"""Podman with its own storage, and a network namespace for containers on the host network.

Everything podman keeps for these tests lives under one folder (``--root``, ``--runroot``,
``--tmpdir``), so the host's images and containers are never touched and the folder goes with the
test. ``--network host`` puts a container in the network namespace of the podman that started it:
started through tests.harness.netns.NetNamespace in its root mode (``unshare -n``), that is a private namespace with only
``lo`` and the multicast route, never the host's network.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

from tests import REPO
from tests.harness.netns import NetNamespace


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


class Podman:
    """``podman`` with storage under ``root`` and no systemd (cgroupfs, events to a file)."""

    def __init__(self, root: Path, driver: str, netns: NetNamespace | None = None) -> None:
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

    def in_netns(self, netns: NetNamespace) -> Podman:
        other = Podman(self.root, self.driver, netns)
        other.run_flags = list(self.run_flags)
        return other

    def reset(self) -> None:
        self("rm", "--all", "--force", timeout=120)
        self("system", "reset", "--force", timeout=120)
