"""npm packages for tests that run a reference client under node (``@mcap/core``, ``@foxglove/ws-protocol``).

They are installed once into ``.cache/npm-tools`` of the checkout (ignored by git, never committed),
under a file lock so two pytest-xdist workers do not install at once; a machine without node or npm,
or whose install fails, skips the test with the reason.
"""

from __future__ import annotations

import fcntl
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from tests import REPO

NPM_DIR = REPO / ".cache" / "npm-tools"
#: What the tests need, pinned to the majors they were written against.
PACKAGES = {"@mcap/core": "2", "@mcap/support": "1", "@foxglove/ws-protocol": "0.8", "ws": "8"}


def node_modules() -> Path:
    """The node_modules holding :data:`PACKAGES` (installed on first use), or a skip."""
    for tool in ("node", "npm"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (Debian: apt-get install nodejs npm)")
    NPM_DIR.mkdir(parents=True, exist_ok=True)
    modules = NPM_DIR / "node_modules"
    wanted = json.dumps(PACKAGES, sort_keys=True)
    stamp = NPM_DIR / "installed.json"
    with (NPM_DIR / ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if stamp.exists() and stamp.read_text() == wanted and modules.is_dir():
            return modules
        specs = [f"{name}@{version}" for name, version in PACKAGES.items()]
        done = subprocess.run(
            ["npm", "install", "--no-audit", "--no-fund", "--no-save", "--prefix", str(NPM_DIR), *specs],
            capture_output=True,
            text=True,
            timeout=300,
        )
        if done.returncode != 0:
            pytest.skip(f"npm install {' '.join(specs)} failed: {done.stderr.strip()[-400:]}")
        stamp.write_text(wanted)
    return modules


def run_node(script: Path, *args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    modules = node_modules()
    env = {"PATH": "/usr/bin:/bin", "NODE_PATH": str(modules)}
    return subprocess.run(
        ["node", str(script), *args], capture_output=True, text=True, timeout=timeout, env=env
    )
