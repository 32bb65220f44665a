"""Run a benchmark inside a private network namespace (never on the host network)."""

from __future__ import annotations

import os
import subprocess
import sys

_MARK = "ANTALATE_BENCH_IN_NETNS"


def ensure_private_netns() -> None:
    """Re-exec this script under ``unshare -rn`` with lo up and a multicast route, once."""
    if os.environ.get(_MARK):
        return
    env = dict(os.environ, **{_MARK: "1"})
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (repo, env.get("PYTHONPATH", "")) if p)
    script = 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec "$@"'
    cmd = ["unshare", "-rn", "sh", "-c", script, "sh", sys.executable, *sys.argv]
    sys.exit(subprocess.call(cmd, env=env))
