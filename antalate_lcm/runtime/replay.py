"""``antalate replay LOG``: run a recorded experiment again and find where it stops matching.

A run on simulated time (``antalate run --speed``) is a pure function of its config, script and
seed (docs/experiments.md, "Deterministic runs"), so the way to check a recording -- against
today's code, another machine, or an edited config -- is to run the nodes again with what was
recorded beside the log (``LOG.run.json``: the config's path and hash, the agents, the script, the
seed) and compare the two logs message by message. The first difference is reported with its
index, channel, simulated time and what differs (the fields of the decoded message, or the
channel, time or length); none means the replay reproduced every byte.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from antalate_lcm import __version__
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.lcm_log import log_events, open_log

if TYPE_CHECKING:
    from antalate_lcm.runtime.experiment import Experiment
    from antalate_lcm.runtime.script import Script

#: Fields of a differing message named in the report, at most.
_FIELDS_SHOWN = 4


def record_path(log: str | Path) -> Path:
    """Where a run's record lives: beside its log."""
    return Path(f"{log}.run.json")


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def write_record(exp: Experiment, script: Script, log: str) -> None:
    """What ``antalate replay`` needs to run ``exp`` again (written after a run on simulated time)."""
    config = Path(exp.config_path).resolve()
    record = {
        "antalate": __version__,
        "config": str(config),
        "config_sha256": file_sha256(config),
        "agents": exp.agents,
        "processes": exp.processes,
        "spacing": exp.spacing,
        "bus": exp.bus,
        "speed": "max" if exp.speed is None or math.isinf(exp.speed) else exp.speed,
        "script": script.model_dump(mode="json", by_alias=True, exclude_defaults=True),
        "log_sha256": file_sha256(log),
    }
    record_path(log).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")


def read_record(log: str | Path) -> dict[str, Any]:
    path = record_path(log)
    if not Path(log).is_file():
        raise AntalateError(f"{log}: no such log")
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AntalateError(
            f"{log}: no {path.name} beside it; only a run on simulated time (antalate run --speed) "
            "records what replay needs"
        ) from None
    except ValueError as exc:
        raise AntalateError(f"{path}: not a run record ({exc})") from None
    if not isinstance(record, dict) or "config" not in record or "script" not in record:
        raise AntalateError(f"{path}: not a run record (no config or script)")
    return record


@dataclass(frozen=True)
class Divergence:
    """The first message where the replay differs from the recording."""

    index: int
    channel: str
    #: Simulated seconds since the recording's first message.
    t: float
    what: str

    def text(self) -> str:
        return f"diverged at message {self.index} ({self.channel}, t = {self.t:.3f} s): {self.what}"


def _events(path: str | Path) -> Iterator[tuple[int, str, bytes]]:
    log = open_log(path)
    try:
        yield from log_events(log)
    finally:
        log.close()


def _decoders() -> dict[bytes, Any]:
    from antalate_lcm import msgs

    out: dict[bytes, Any] = {}
    for name in dir(msgs):
        cls = getattr(msgs, name)
        fp = getattr(cls, "_get_packed_fingerprint", None)
        if fp is not None and name != "header_t":
            out[fp()] = cls
    return out


def _flat(value: Any, prefix: str, into: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flat(v, f"{prefix}.{k}" if prefix else k, into)
    elif isinstance(value, list) and len(value) <= 64:
        for i, v in enumerate(value):
            _flat(v, f"{prefix}[{i}]", into)
    else:
        into[prefix] = value


def describe(recorded: bytes, replayed: bytes) -> str:
    """What differs between two encodings of one message: its fields, when antalate can decode it."""
    cls = _decoders().get(recorded[:8])
    if cls is None or replayed[:8] != recorded[:8]:
        return f"the bytes differ ({len(recorded)} recorded, {len(replayed)} replayed)"
    from antalate_lcm.wire.lcm_json import to_json

    try:
        a: dict[str, Any] = {}
        b: dict[str, Any] = {}
        _flat(to_json(cls.decode(recorded)), "", a)
        _flat(to_json(cls.decode(replayed)), "", b)
    except Exception:  # noqa: BLE001 - a damaged recording: say so rather than fail
        return f"the bytes differ and one does not decode as {cls.__name__}"
    diffs = [k for k in dict.fromkeys([*a, *b]) if a.get(k) != b.get(k)]
    shown = ", ".join(f"{k}: {a.get(k)!r} recorded, {b.get(k)!r} replayed" for k in diffs[:_FIELDS_SHOWN])
    more = f" (and {len(diffs) - _FIELDS_SHOWN} more fields)" if len(diffs) > _FIELDS_SHOWN else ""
    return f"{cls.__name__} {shown}{more}" if diffs else f"the bytes of {cls.__name__} differ"


def first_divergence(recorded: str | Path, replayed: str | Path) -> Divergence | None:
    """The first event where two logs differ (channel, time or bytes), None when they are equal."""
    a, b = _events(recorded), _events(replayed)
    t0: int | None = None
    index = 0
    while True:
        x, y = next(a, None), next(b, None)
        if x is None and y is None:
            return None
        ref = x or y
        assert ref is not None
        if t0 is None:
            t0 = ref[0]
        t = (ref[0] - t0) / 1e6
        if x is None:
            assert y is not None
            return Divergence(index, y[1], t, f"the recording ends here; the replay goes on with {y[1]}")
        if y is None:
            return Divergence(index, x[1], t, "the replay ends here; the recording goes on")
        if x[1] != y[1]:
            return Divergence(index, x[1], t, f"channel {x[1]} recorded, {y[1]} replayed")
        if x[0] != y[0]:
            return Divergence(index, x[1], t, f"time {t:.6f} s recorded, {(y[0] - t0) / 1e6:.6f} s replayed")
        if x[2] != y[2]:
            return Divergence(index, x[1], t, describe(x[2], y[2]))
        index += 1


@dataclass
class ReplayResult:
    messages: int
    divergence: Divergence | None
    notes: list[str]

    def text(self) -> str:
        lines = list(self.notes)
        if self.divergence is None:
            lines.append(f"replay matches the recording: {self.messages} messages, byte for byte")
        else:
            lines.append(self.divergence.text())
        return "\n".join(lines)


def replay(log: str | Path, *, config: str | None = None, keep: str | None = None) -> ReplayResult:
    """Run the experiment recorded beside ``log`` again (with ``config`` instead of the recorded
    one if given) and compare; ``keep``: where to leave the replayed log (else a temporary file)."""
    from antalate_lcm.runtime.experiment import Experiment, run
    from antalate_lcm.runtime.script import parse_script

    record = read_record(log)
    notes: list[str] = []
    config_path = config or str(record["config"])
    if not Path(config_path).is_file():
        raise AntalateError(f"{config_path}: the recorded run's config is gone (pass --config FILE)")
    if file_sha256(config_path) != record.get("config_sha256"):
        notes.append(f"note: {config_path} is not the file the run was recorded with")
    if record.get("antalate") != __version__:
        notes.append(f"note: recorded with antalate {record.get('antalate')}, replayed with {__version__}")
    script = parse_script(dict(record["script"]), f"{record_path(log)}: script")
    with tempfile.TemporaryDirectory(prefix="antalate-replay-") as tmp:
        out = keep or str(Path(tmp) / "replay.lcm")
        outcome = run(
            Experiment(
                config_path=config_path,
                agents=int(record["agents"]),
                processes=int(record.get("processes", 1)),
                spacing=float(record["spacing"]),
                script=script,
                output=out,
                bus=record.get("bus"),
                force=True,
                speed=math.inf,
                seed=script.seed,
                log_level="WARNING",
            )
        )
        return ReplayResult(outcome.messages, first_divergence(log, out), notes)


def cmd_replay(args: argparse.Namespace) -> int:
    quiet = logging.getLogger("antalate")
    level = quiet.level
    if args.log_level == "INFO":  # the default: the replayed nodes' lines would bury the verdict
        quiet.setLevel(logging.WARNING)
    try:
        result = replay(args.log, config=args.config, keep=args.output)
    finally:
        quiet.setLevel(level)
    print(result.text(), flush=True)
    return 0 if result.divergence is None else 1


def replay_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="the LCM log of a run on simulated time (its LOG.run.json beside it)")
    p.add_argument("--config", metavar="FILE", help="replay with this config instead of the recorded one")
    p.add_argument(
        "-o", "--output", metavar="LOG", help="keep the replayed log here (default: a temporary file)"
    )
