"""``antalate sweep SPEC``: many ``antalate run`` experiments over parameters and seeds, one table.

The spec (TOML, :mod:`.sweep_spec`) names a config, a script, the parameters' values and the seeds;
every combination with every seed is one run: one ``antalate run --headless --json`` child process
(its own bus, its own failure), in ``OUT/runs/NNNN/`` with the exact config and script it flew, its
LCM log and its output. The runs go in parallel (``--jobs``, default one per core); each one that
ends adds one row to ``OUT/results.csv`` and ``OUT/results.json`` at once (parameters, seed,
status, and the swarm metrics of ``antalate analyze``), so an interrupted sweep keeps every row it
finished. A run that fails (a flight that does not come back, a process that dies, a time-out) is
a row with ``status = failed`` and its ``reason``, and the sweep carries on.

Parallel runs must not hear each other: each bus's transport says how to keep them apart
(:meth:`~antalate_lcm.transports.base.Transport.for_slot`): ``memq://`` buses stay inside their run's
process; with ``--jobs`` above 1 the ``udpm://`` buses of the k-th parallel slot get the port + 100 k
(the same group), and ``zenoh://`` buses are refused. The table and the progress line are
:mod:`.sweep_results`.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import IO, Any

from antalate_lcm.base.errors import AntalateError, BusUnavailable, ConfigError
from antalate_lcm.core.config import read_toml_file
from antalate_lcm.runtime.sweep_results import (
    HEAD,
    METRICS,
    TAIL,
    Progress,
    ResultsTable,
    columns,
    count,
    metrics_row,
)
from antalate_lcm.runtime.sweep_spec import Point, Sweep, build, dumps_toml, parse_spec
from antalate_lcm.transports import Transport, transport_for

#: Port offset between two parallel slots' udpm:// buses.
SLOT_PORT_STEP = 100
#: s a run has to stop after SIGINT (its nodes stop in order) before it is killed.
STOP_GRACE = 30.0


def load_sweep(path: str | Path) -> Sweep:
    """Read a spec and the config and script it names, and check every run (one-line errors)."""
    p = Path(path)
    spec = parse_spec(read_toml_file(p), str(p))
    config_path = p.parent / spec.config
    if not config_path.is_file():
        raise ConfigError(str(p), "config", f"an agent config file ({config_path} is not one)")
    script_doc = None
    if spec.script is not None:
        script_path = p.parent / spec.script
        if not script_path.is_file():
            raise ConfigError(str(p), "script", f"an experiment script file ({script_path} is not one)")
        script_doc = read_toml_file(script_path)
        from antalate_lcm.runtime.script import parse_script

        parse_script(script_doc, str(script_path))  # its own errors name its own file
    return build(spec, read_toml_file(config_path), script_doc, str(p))


# ----------------------------------------------------------------------------- one run
@dataclass
class _Run:
    point: Point
    folder: Path
    slot: int
    proc: subprocess.Popen[bytes]
    started: float
    out: IO[bytes]
    err: IO[bytes]
    #: s it may take before the sweep stops it.
    timeout: float
    stopping: str = ""
    stop_sent: float = 0.0


def slot_buses(config: dict[str, Any], slot: int, jobs: int) -> None:
    """Keep parallel runs apart: each bus as its transport moves it for slot k (udpm: port + 100 k;
    none with one job); a transport that cannot keep runs apart (zenoh) is refused."""
    buses = config.get("buses")
    if jobs <= 1 or not isinstance(buses, dict):
        return
    for name, url in buses.items():
        transport = _transport(url)
        if transport is None:
            continue
        try:
            buses[name] = transport.for_slot(slot, SLOT_PORT_STEP)
        except ValueError as exc:
            raise AntalateError(f"buses.{name} = {url!r}: {exc}") from None


def _transport(url: object) -> Transport | None:
    """``url``'s transport; None for what is not a valid bus URL (the config's own check says why)."""
    if not isinstance(url, str):
        return None
    try:
        return transport_for(url)
    except BusUnavailable:
        return None


def check_slots(sweep: Sweep, jobs: int) -> None:
    """Every slot's buses are valid and apart from the other slots' (before anything flies)."""
    used: dict[int, tuple[int, str]] = {}
    for slot in range(jobs):
        config, _ = sweep.documents(sweep.points[0])
        slot_buses(config, slot, jobs)
        for name, url in config.get("buses", {}).items():
            transport = _transport(url)
            if transport is not None and transport.apart_by_port:
                port = transport.url.port
                other = used.setdefault(port, (slot, name))
                if other[0] != slot:
                    raise AntalateError(
                        f"buses.{name}: parallel slot {slot} would share port {port} with slot {other[0]}'s "
                        f"bus {other[1]!r}; use --jobs 1 or ports more than {SLOT_PORT_STEP * jobs} apart"
                    )


def run_argv(sweep: Sweep, folder: Path, log_level: str = "WARNING") -> list[str]:
    spec = sweep.spec
    argv = [
        sys.executable,
        "-m",
        "antalate_lcm.cli",
        "--log-level",
        log_level,
        "run",
        str(folder / "config.toml"),
    ]
    argv += [
        "--agents",
        str(spec.agents),
        "--processes",
        str(spec.processes),
        "--spacing",
        repr(spec.spacing),
    ]
    if spec.speed is not None:  # simulated time: the run is a function of its script's seed
        argv += ["--speed", spec.speed if isinstance(spec.speed, str) else repr(spec.speed)]
    argv += [
        "--headless",
        "--script",
        str(folder / "script.toml"),
        "-o",
        str(folder / "flight.lcm"),
        "-f",
        "--json",
    ]
    return argv


def _start(sweep: Sweep, point: Point, out_dir: Path, slot: int, jobs: int) -> _Run:
    from antalate_lcm.runtime.agent import _die_with_parent

    folder = out_dir / "runs" / f"{point.index:04d}"
    folder.mkdir(parents=True, exist_ok=True)
    config, script = sweep.documents(point)
    slot_buses(config, slot, jobs)
    (folder / "config.toml").write_text(dumps_toml(config), encoding="utf-8")
    (folder / "script.toml").write_text(dumps_toml(script), encoding="utf-8")
    out = (folder / "outcome.json").open("wb")
    err = (folder / "output.log").open("wb")
    proc = subprocess.Popen(
        run_argv(sweep, folder),
        stdout=out,
        stderr=err,
        stdin=subprocess.DEVNULL,
        start_new_session=True,  # a Ctrl-C reaches the sweep, which stops its runs in order
        preexec_fn=_die_with_parent,
    )
    return _Run(point, folder, slot, proc, time.monotonic(), out, err, sweep.run_timeout(point))


def _finish(run: _Run, code: int, out_dir: Path) -> dict[str, Any]:
    """The run's row, from its exit status, its JSON outcome and its stderr."""
    run.out.close()
    run.err.close()
    wall = time.monotonic() - run.started
    row: dict[str, Any] = {"run": run.point.index, "seed": run.point.seed, "wall_s": round(wall, 2)}
    row.update(dict(run.point.values))
    outcome: dict[str, Any] | None = None
    try:
        outcome = json.loads((run.folder / "outcome.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        outcome = None
    analysis = outcome.get("analysis") if outcome else None
    row.update(metrics_row(analysis))
    row["messages"] = outcome.get("messages") if outcome else None
    log = run.folder / "flight.lcm"
    row["log"] = os.path.relpath(log, out_dir) if log.exists() else None
    if code == 0 and outcome is not None and outcome.get("ok"):
        row["status"], row["reason"] = "ok", ""
        return row
    row["status"] = "interrupted" if run.stopping == "interrupted" else "failed"
    row["reason"] = run.stopping or _reason(code, outcome, run.folder / "output.log")
    return row


def _reason(code: int, outcome: dict[str, Any] | None, stderr: Path) -> str:
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    if outcome is not None:
        failed = [line for line in str(outcome.get("report", "")).splitlines() if line.startswith("FAILED")]
        if failed:
            return failed[0]
        if outcome.get("problem"):
            return f"no metrics: {outcome['problem']}"
    try:
        lines = [
            line for line in stderr.read_text(encoding="utf-8", errors="replace").splitlines() if line.strip()
        ]
    except OSError:
        lines = []
    errors = [line for line in lines if line.startswith("antalate:") or "Error" in line]
    last = (errors or lines or [""])[-1].strip()
    return f"exit status {code}" + (f": {last}" if last else "")


# ----------------------------------------------------------------------------- the sweep
@dataclass
class SweepResult:
    table: ResultsTable
    interrupted: bool = False
    rows: list[dict[str, Any]] = field(default_factory=list)

    @property
    def failed(self) -> int:
        return sum(1 for r in self.table.rows if r["status"] != "ok")


def prepare_output(out_dir: Path, force: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise AntalateError(f"{out_dir} exists and is not a folder")
    if (out_dir / "results.csv").exists() and not force:
        raise AntalateError(
            f"{out_dir} holds a sweep's results: pass --force to overwrite them, or -o another folder"
        )
    out_dir.mkdir(parents=True, exist_ok=True)


def run_sweep(
    sweep: Sweep,
    out_dir: Path,
    *,
    jobs: int,
    progress: Progress,
    stop: Callable[[], bool] = lambda: False,
) -> SweepResult:
    """Run every point, ``jobs`` at a time, until done or ``stop()``; the table is on disk throughout."""
    table = ResultsTable(out_dir, columns(sweep))
    table.write()
    result = SweepResult(table)
    pending = list(sweep.points)
    running: dict[int, _Run] = {}  # by slot
    try:
        while pending or running:
            if stop() and not result.interrupted:
                result.interrupted = True
                pending.clear()
                for run in running.values():
                    _stop(run, "interrupted")
            while pending and len(running) < jobs:
                slot = next(s for s in range(jobs) if s not in running)
                running[slot] = _start(sweep, pending.pop(0), out_dir, slot, jobs)
            progress.draw(running=len(running))
            time.sleep(0.1)
            now = time.monotonic()
            for slot, run in list(running.items()):
                code = run.proc.poll()
                if code is None:
                    if not run.stopping and now - run.started > run.timeout:
                        _stop(run, f"timed out after {run.timeout:.0f} s (the sweep's timeout)")
                    elif run.stopping and now - run.stop_sent > STOP_GRACE:
                        run.proc.kill()
                    continue
                del running[slot]
                row = _finish(run, code, out_dir)
                table.add(row)
                result.rows.append(row)
                progress.ended(row, run.point.label())
    finally:
        for run in running.values():  # an exception here: leave no run behind
            if run.proc.poll() is None:
                run.proc.kill()
                run.proc.wait()
        progress.close()
    return result


def _stop(run: _Run, why: str) -> None:
    run.stopping, run.stop_sent = why, time.monotonic()
    if run.proc.poll() is None:
        run.proc.send_signal(signal.SIGINT)  # `antalate run` lands its agents and writes its outcome


def cmd_sweep(args: argparse.Namespace) -> int:
    sweep = load_sweep(args.spec)
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 1:
        raise AntalateError(f"--jobs wants a number >= 1 (got {jobs})")
    jobs = min(jobs, len(sweep.points))
    check_slots(sweep, jobs)
    out_dir = Path(args.output or Path(args.spec).with_suffix("").name + "-results")
    prepare_output(out_dir, args.force)
    signalled: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        signalled.append(signum)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        progress = Progress(len(sweep.points), sys.stderr)
        print(
            f"sweep: {len(sweep.points)} runs ({count(len(sweep.points) // len(sweep.seeds), 'point')} x "
            f"{count(len(sweep.seeds), 'seed')}), {jobs} at a time, into {out_dir}",
            file=sys.stderr,
            flush=True,
        )
        result = run_sweep(sweep, out_dir, jobs=jobs, progress=progress, stop=lambda: bool(signalled))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    rows = result.table.rows
    print(
        f"{len(rows)} of {len(sweep.points)} runs, {result.failed} failed"
        + (" (interrupted: the rows so far are written)" if result.interrupted else "")
        + f"; table: {result.table.csv} and {result.table.json}",
        flush=True,
    )
    if result.interrupted:
        return 130
    return 1 if result.failed else 0


def sweep_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", help="sweep spec (TOML): config, script, agents, seeds, [parameters]")
    p.add_argument(
        "-o", "--output", metavar="DIR", help="folder of the table and the runs (default: SPEC-results)"
    )
    p.add_argument("-j", "--jobs", type=int, metavar="J", help="runs at a time (default: one per core)")
    p.add_argument(
        "-f", "--force", action="store_true", help="overwrite the results of an earlier sweep in DIR"
    )


__all__ = [
    "HEAD",
    "METRICS",
    "SLOT_PORT_STEP",
    "TAIL",
    "Progress",
    "ResultsTable",
    "SweepResult",
    "check_slots",
    "cmd_sweep",
    "columns",
    "load_sweep",
    "metrics_row",
    "prepare_output",
    "run_argv",
    "run_sweep",
    "slot_buses",
    "sweep_arguments",
]
