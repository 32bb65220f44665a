"""What is an extra says so: ``antalate plot`` without matplotlib, a Tello agent without djitellopy.

The container image and a MAVLink vehicle computer leave these libraries out (pyproject's extras,
containers/Containerfile), so the user who needs one gets one line naming the pip command, never a
traceback; the HLC stays up, reporting it, and the config still validates. The libraries are hidden
from a real ``antalate`` process (``sys.modules[name] = None`` makes its import fail), since the test
environment installs them through the ``dev`` extra.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from antalate_lcm.apps.analysis.plot import MATPLOTLIB_MISSING
from antalate_lcm.core.config import load_config
from antalate_lcm.vehicles import AutopilotError
from antalate_lcm.vehicles.tello import DJITELLOPY_MISSING, TelloAdapter
from tests import REPO


def antalate_without(module: str, *argv: str, **kw: Any) -> subprocess.Popen[str]:
    """``antalate ARGV`` in a fresh interpreter in which ``import MODULE`` fails."""
    code = (
        f"import sys; sys.modules[{module!r}] = None; from antalate_lcm.cli import main; "
        f"sys.exit(main({list(argv)!r}))"
    )
    proc: subprocess.Popen[str] = subprocess.Popen(
        [sys.executable, "-c", code],
        cwd=REPO,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        **kw,
    )
    return proc


def tello_config(tmp_path: Path) -> Path:
    doc = {
        "agent": {"name": "tello-1"},
        "buses": {"lan": "memq://"},
        "security": {"swarm_key": "extras-test-key", "state_dir": str(tmp_path / "state")},
        "hlc": {"autopilot": "tello", "autopilot_params": {"host": "127.0.0.1"}},
    }
    path = tmp_path / "tello.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def test_plot_without_matplotlib_says_which_extra_to_install(tmp_path: Path) -> None:
    log = tmp_path / "flight.lcm"
    log.write_bytes(b"")
    proc = antalate_without("matplotlib", "plot", str(log))
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, out + err
    assert err.strip() == f"antalate: {MATPLOTLIB_MISSING}", err
    assert "pip install 'antalate[plot]'" in err and "Traceback" not in err
    assert not (tmp_path / "flight.png").exists()


def test_tello_connect_without_djitellopy_says_which_extra_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "djitellopy", None)
    ap = TelloAdapter({"host": "127.0.0.1"})
    with pytest.raises(AutopilotError) as err:
        ap.connect()
    assert str(err.value) == DJITELLOPY_MISSING and "pip install 'antalate[tello]'" in str(err.value)
    # nothing was claimed: a later connect (djitellopy installed meanwhile) is not refused as a second user
    with pytest.raises(AutopilotError, match=r"antalate\[tello\]"):
        ap.connect()


def test_a_tello_config_validates_without_djitellopy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "djitellopy", None)
    config = load_config(tello_config(tmp_path))
    assert config.hlc.autopilot == "tello"


def test_a_tello_hlc_without_djitellopy_reports_the_extra_and_stays_up(tmp_path: Path) -> None:
    proc = antalate_without("djitellopy", "hlc", str(tello_config(tmp_path)))
    try:
        deadline = time.monotonic() + 60
        lines: list[str] = []
        assert proc.stderr is not None
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            lines.append(line)
            if "antalate[tello]" in line:
                break
        said = "".join(lines)
        reported = [ln for ln in lines if "pip install 'antalate[tello]'" in ln]
        assert reported, said
        assert DJITELLOPY_MISSING in reported[0] and "Traceback" not in said, said
        assert proc.poll() is None, f"the HLC exited ({proc.returncode}):\n{said}"
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
