"""video_capture with a real ffmpeg (lavfi test source), a missing ffmpeg and a bad device."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from behaviors.video_capture import VideoCapture
from tests.harness.bma import AGENT, harness, make_config
from tests.harness.polling import wait_for

needs_ffmpeg = pytest.mark.skipif(
    shutil.which("ffmpeg") is None or shutil.which("ffprobe") is None,
    reason="ffmpeg/ffprobe not installed (apt-get install ffmpeg; CI: tools/install-system-deps.sh)",
)


def _config(tmp_path: Path, **params: Any) -> Any:
    p = {
        "input": "testsrc=size=160x120:rate=10",
        "format": "lavfi",
        "input_args": ["-re"],
        "output_args": ["-c:v", "mpeg4"],
        "output_dir": str(tmp_path / "videos"),
        **params,
    }
    return make_config(
        [{"name": "video", "behaviors": [{"plugin": "video_capture", "params": p, "tick_hz": 20}]}]
    )


def _probe(path: Path) -> dict[str, Any]:
    out = subprocess.run(
        [
            "ffprobe",
            "-v",
            "error",
            "-count_frames",
            "-show_entries",
            "stream=codec_type,nb_read_frames:format=duration",
            "-of",
            "json",
            str(path),
        ],
        capture_output=True,
        text=True,
        timeout=20,
        check=True,
    )
    report: dict[str, Any] = json.loads(out.stdout)
    return report


@needs_ffmpeg
def test_records_a_playable_file_while_active(tmp_path: Path) -> None:
    with harness(_config(tmp_path)) as h:
        node = h.bma("video")
        h.mc_state("STANDBY")
        h.mc_state("TAKEOFF")
        assert wait_for(lambda: h.sync(node.active) == ["video_capture"])
        cap: VideoCapture = h.sync(lambda: node.behavior("video_capture"))
        h.mc_state("MISSION")  # a state change while active does not restart the recording
        time.sleep(1.0)
        h.mc_state("STANDBY")
        assert wait_for(lambda: h.sync(node.active) == [])
        assert cap.wait_stopped(15), "ffmpeg did not stop"
        assert h.sync(node.failures) == {}
    assert len(cap.recordings) == 1
    path = cap.recordings[0]
    assert path.parent == tmp_path / "videos" and path.name.startswith(f"{AGENT}-video_capture-")
    info = _probe(path)
    video = [s for s in info["streams"] if s["codec_type"] == "video"]
    assert video and int(video[0]["nb_read_frames"]) >= 5
    assert float(info["format"]["duration"]) > 0.4


@needs_ffmpeg
def test_each_activation_gets_its_own_file(tmp_path: Path) -> None:
    with harness(_config(tmp_path, filename="clip.mkv")) as h:
        node = h.bma("video")
        for _ in range(2):
            h.mc_state("MISSION")
            assert wait_for(lambda: h.sync(node.active))
            time.sleep(0.3)
            h.mc_state("STANDBY")
            assert wait_for(lambda: not h.sync(node.active))
        cap: VideoCapture = h.sync(lambda: node.behavior("video_capture"))
        assert cap.wait_stopped(15)
    assert [p.name for p in cap.recordings] == ["clip.mkv", "clip-1.mkv"]
    assert all(p.stat().st_size > 0 for p in cap.recordings)


def test_missing_ffmpeg_is_reported_as_a_failure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))
    with harness(_config(tmp_path)) as h:
        status = h.record("ARBITER", arbiter="video")
        node = h.bma("video")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.failures))
        expected = "video_capture: ffmpeg not found ('ffmpeg' is not on PATH): apt-get install ffmpeg (in on_activate)"
        assert wait_for(lambda: any(expected in list(m.failed) for m in status))
        assert h.sync(node.active) == []


@needs_ffmpeg
def test_ffmpeg_exiting_early_is_reported_with_its_message(tmp_path: Path) -> None:
    config = _config(tmp_path, input=str(tmp_path / "no-such-camera"), format="v4l2", input_args=[])
    with harness(config) as h:
        node = h.bma("video")
        h.mc_state("MISSION")
        failures = wait_for(lambda: h.sync(node.failures), timeout=10)
        reason = failures["video_capture"]
        assert (
            reason.startswith("ffmpeg exited with code ")
            and "no-such-camera" in reason
            and reason.endswith("(in tick)")
        )
        assert h.sync(node.active) == []


def test_a_stuck_ffmpeg_is_interrupted_then_killed(tmp_path: Path) -> None:
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\ntrap '' INT\nexec sleep 60\n")  # ignores q and SIGINT
    fake.chmod(0o755)
    with harness(_config(tmp_path, ffmpeg=str(fake), stop_timeout=0.2)) as h:
        node = h.bma("video")
        h.mc_state("MISSION")
        assert wait_for(lambda: h.sync(node.active))
        cap: VideoCapture = h.sync(lambda: node.behavior("video_capture"))
        proc = cap.proc
        assert proc is not None
        t0 = time.monotonic()
        h.mc_state("STANDBY")
        assert wait_for(lambda: not h.sync(node.active))
        assert cap.wait_stopped(5)
        assert proc.returncode == -9 and time.monotonic() - t0 < 3
