"""``video_capture``: record video with ``ffmpeg`` while active, and stop it so the file is playable.

As in the paper's template application it neither subscribes nor publishes; it only follows the
arbiter. Each activation writes a new file. ffmpeg runs in its own process group, so a Ctrl-C on
the terminal reaches the BMA, not ffmpeg: the BMA then stops it in order — ``q`` on its stdin (ffmpeg
finishes the file: an MP4 without this has no index and does not play), then SIGINT, then SIGKILL,
each after ``stop_timeout``. The stop runs on a separate (non-daemon) thread so the rest of the
agent is not held up while ffmpeg flushes, and the process does not exit before the file is done.

Failures are reported through the BMA: ffmpeg missing → on activation; ffmpeg exiting by itself
(a bad device, an unsupported format) → on the next tick, with ffmpeg's last message.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import IO

from pydantic import BaseModel, ConfigDict, Field, field_validator

from antalate_lcm.core.behavior import Behavior, BehaviorContext, BehaviorError


class VideoCapture(Behavior):
    """ffmpeg from ``input`` (a device or a lavfi source) to ``output_dir`` while active."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

        #: ffmpeg input, e.g. "/dev/video0" (format v4l2) or "testsrc=size=320x240:rate=10" (format lavfi).
        input: str = Field(min_length=1)
        #: ffmpeg input format (-f), e.g. "v4l2", "lavfi"; empty = let ffmpeg probe.
        format: str = ""
        #: Directory for the recordings (created if missing; ~ is expanded).
        output_dir: str = "videos"
        #: File name; fields {agent}, {name} (behavior name), {time} (YYYYmmdd-HHMMSS, local).
        #: The extension picks the container; Matroska (.mkv) stays readable even after a hard kill.
        filename: str = "{agent}-{name}-{time}.mkv"
        #: Arguments before -i (input options), e.g. ["-framerate", "30", "-video_size", "640x480"];
        #: ["-re"] for a lavfi test source, which otherwise runs as fast as the CPU allows.
        input_args: list[str] = Field(default_factory=list)
        #: Arguments before the output file, e.g. ["-c:v", "libx264", "-preset", "ultrafast"].
        output_args: list[str] = Field(default_factory=list)
        #: The ffmpeg executable (name on PATH or a path).
        ffmpeg: str = "ffmpeg"
        #: Seconds to wait for each stop step (q, then SIGINT) before the next.
        stop_timeout: float = Field(default=5.0, gt=0, allow_inf_nan=False)

        @field_validator("filename")
        @classmethod
        def _known_fields(cls, v: str) -> str:
            try:
                name = v.format(agent="a", name="n", time="t")
            except (KeyError, IndexError, ValueError) as exc:
                raise ValueError(f"may only use the fields {{agent}}, {{name}}, {{time}} ({exc!r})") from None
            if not name or "/" in name:
                raise ValueError("must be a file name, without '/' (the directory is output_dir)")
            return v

    params: Params
    activate_on = ("TAKEOFF", "MISSION", "RTL", "LAND", "MANUAL")
    tick_hz = 2.0

    def __init__(self, ctx: BehaviorContext) -> None:
        super().__init__(ctx)
        self.proc: subprocess.Popen[bytes] | None = None
        self.path: Path | None = None
        #: Every file this instance has recorded (or is recording), in order.
        self.recordings: list[Path] = []
        self._stderr: collections.deque[str] = collections.deque(maxlen=20)
        self._stoppers: list[threading.Thread] = []
        self._drainer: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def on_activate(self) -> None:
        p = self.params
        exe = shutil.which(p.ffmpeg)
        if exe is None:
            raise BehaviorError(f"ffmpeg not found ({p.ffmpeg!r} is not on PATH): apt-get install ffmpeg")
        out_dir = Path(p.output_dir).expanduser()
        out_dir.mkdir(parents=True, exist_ok=True)
        path = _unique(
            out_dir
            / p.filename.format(agent=self.ctx.agent, name=self.ctx.name, time=time.strftime("%Y%m%d-%H%M%S"))
        )
        argv = [exe, "-hide_banner", "-nostats", "-loglevel", "warning", "-y", *p.input_args]
        if p.format:
            argv += ["-f", p.format]
        argv += ["-i", p.input, *p.output_args, str(path)]
        self.log.info("recording to %s: %s", path, " ".join(argv))
        self._stderr = collections.deque(maxlen=20)
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            start_new_session=True,
        )
        self.path = path
        self.recordings.append(path)
        assert self.proc.stderr is not None
        self._drainer = threading.Thread(
            target=_drain,
            args=(self.proc.stderr, self._stderr, self.log),
            name=f"ffmpeg-stderr {path.name}",
            daemon=True,
        )
        self._drainer.start()

    def tick(self, dt: float) -> None:
        proc = self.proc
        if proc is None or proc.poll() is None:
            return
        self.proc = None
        if proc.returncode == 0:
            self.log.info("ffmpeg finished on its own (the input ended): %s", self.path)
            return
        if self._drainer is not None:
            self._drainer.join(1.0)  # ffmpeg's last words may still be in the pipe
        last = self._last_error()
        raise BehaviorError(f"ffmpeg exited with code {proc.returncode}: {last}")

    def on_deactivate(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None:
            return
        if proc.poll() is None and proc.stdin is not None:
            with contextlib.suppress(OSError):  # ffmpeg already gone: the stopper reaps it
                proc.stdin.write(b"q")
                proc.stdin.flush()
        stopper = threading.Thread(
            target=self._stop, args=(proc, self.path), name=f"ffmpeg-stop {self.path}", daemon=False
        )
        self._stoppers.append(stopper)
        stopper.start()

    def wait_stopped(self, timeout: float | None = None) -> bool:
        """Block until every ffmpeg this behavior started has exited and its file is final."""
        deadline = None if timeout is None else time.monotonic() + timeout
        for t in list(self._stoppers):
            t.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
        self._stoppers = [t for t in self._stoppers if t.is_alive()]
        return not self._stoppers

    # ------------------------------------------------------------------ internals
    def _stop(self, proc: subprocess.Popen[bytes], path: Path | None) -> None:
        timeout = self.params.stop_timeout
        for sig in (None, signal.SIGINT, signal.SIGKILL):
            if sig is not None:
                self.log.warning("ffmpeg did not stop within %g s; sending %s", timeout, sig.name)
                try:
                    os.killpg(proc.pid, sig)
                except ProcessLookupError:
                    break
            try:
                proc.wait(timeout)
                break
            except subprocess.TimeoutExpired:
                continue
        if proc.stdin is not None:
            with contextlib.suppress(OSError):
                proc.stdin.close()
        rc = proc.wait()
        if rc == 0:
            self.log.info("recording finished: %s", path)
        else:
            self.log.warning(
                "ffmpeg ended with code %s (%s); the file %s may be incomplete", rc, self._last_error(), path
            )

    def _last_error(self) -> str:
        return self._stderr[-1] if self._stderr else "(no message)"


def _drain(stream: IO[bytes], lines: collections.deque[str], log: logging.Logger) -> None:
    """Read ffmpeg's stderr to the end so it never blocks on a full pipe; keep the last lines."""
    for raw in iter(stream.readline, b""):
        line = raw.decode(errors="replace").strip()
        if line:
            lines.append(line)
            log.debug("ffmpeg: %s", line)
    stream.close()


def _unique(path: Path) -> Path:
    """``path``, or ``name-1.ext``, ``name-2.ext``, ...: never overwrite an earlier recording."""
    if not path.exists():
        return path
    n = 1
    while True:
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
        if not candidate.exists():
            return candidate
        n += 1
