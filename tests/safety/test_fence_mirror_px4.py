"""The swarm fence mirrored into PX4's own GF_* parameters on the real PX4 v1.15.4 SITL (SIH): written by
the px4 adapter (GF_ACTION is an INT32, packed byte-wise once its type is read), read back by the adapter
and then by a fresh PARAM_REQUEST_READ. Instance 8 (other PX4 tests use lower ones), on the loopback of a
private network namespace, under the shared SITL lock like every firmware test (docs/safety.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests import REPO
from tests.conftest import _netns_reason
from tests.harness.netns import NetNamespace
from tests.harness.process import child_env, stop_process
from tests.sitl_px4.harness import link_commands, sitl_dir, sitl_missing

pytestmark = [pytest.mark.netns, pytest.mark.timeout(240)]

INSTANCE = 8


@pytest.fixture(scope="module")
def px4(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[NetNamespace, Path]]:
    reason = sitl_missing() or _netns_reason()
    if reason:
        pytest.skip(reason)
    work = tmp_path_factory.mktemp("px4")
    link_commands(work / "px4")
    with NetNamespace() as ns:
        proc = ns.popen(
            ["sh", str(sitl_dir() / "run-px4-sih.sh"), str(INSTANCE), str(work / "px4")],
            env={**child_env(), "PX4_PARAMS": "SDLOG_MODE=-1"},
            stdin=subprocess.DEVNULL,
            stdout=open(work / "px4.log", "w"),  # noqa: SIM115 - closed with the process
            stderr=subprocess.STDOUT,
        )
        try:
            yield ns, work / "px4.log"
        finally:
            stop_process(proc)


def test_the_gf_parameters_are_written_and_read_back(px4: tuple[NetNamespace, Path]) -> None:
    ns, px4_log = px4
    # connect, mirror, read back; one JSON line out
    out = ns.run(
        [sys.executable, "-m", "tests.children.px4_fence_mirror", str(14540 + INSTANCE)],
        timeout=180,
        cwd=str(REPO),
    )
    assert out.returncode == 0, out.stderr[-2000:] + (px4_log.read_text()[-2000:] if px4_log.exists() else "")
    r = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"\nPX4 GF_* before {r['before']}, wanted {r['wanted']}, read back {r['after']}")
    assert r["problems"] == []
    # PX4's defaults: no horizontal or vertical limit, GF_ACTION 2 (Hold); now the cylinder and Land (5)
    assert r["before"]["GF_MAX_HOR_DIST"] == 0.0 and r["before"]["GF_MAX_VER_DIST"] == 0.0
    for name, value in r["wanted"].items():
        assert r["after"][name] == pytest.approx(value, abs=0.05), name
    assert r["after"]["GF_ACTION"] == 5.0
