"""What ``antalate sweep`` reports: the results table (``results.csv`` and ``results.json``, one row per
run with its parameters, seed, status and the swarm metrics of ``antalate analyze``) and the progress
it prints while the runs go."""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path
from typing import IO, Any

from antalate_lcm.runtime.sweep_spec import Sweep

#: The table's columns before the parameters and after them (the metrics: :func:`metrics_row`).
HEAD = ("run",)
TAIL = ("seed", "status", "reason", "wall_s", "messages")
METRICS = (
    "agents",
    "mission_s",
    "radius_start",
    "radius_end",
    "radius_max",
    "radius_mean",
    "mean_distance_mean",
    "min_separation",
    "nn_median",
    "polarisation_mean",
    "polarisation_end",
    "connected_fraction",
    "cohesion_ratio",
    "radius_below_after",
    "radius_above_after",
    "drift_error_deg",
    "drift_speed",
    "faults",
    "broadcast_offered",
    "broadcast_heard",
    "log",
)


# ----------------------------------------------------------------------------- the table
def columns(sweep: Sweep) -> list[str]:
    return [*HEAD, *sweep.parameters, *TAIL, *METRICS]


def _phase(analysis: dict[str, Any], name: str) -> dict[str, Any]:
    return next((p for p in analysis.get("phases", []) if p["phase"]["name"] == name), {})


def metrics_row(analysis: dict[str, Any] | None) -> dict[str, Any]:
    """The table's metrics from ``antalate run --json``'s ``analysis`` (None: every metric empty).

    Over the mission phase (the whole swarm in MISSION; docs/logging.md, "Analyse"): the radius at
    its start and end, its largest and mean value; the mean distance to the centroid (mean); the
    minimum separation; the median nearest-neighbour distance; the polarisation (mean, end); the
    fraction of samples with the proximity graph connected; the cohesion ratio; the seconds from
    the mission's start to the script's radius_below / radius_above crossings; the mean absolute
    drift error against the commanded directions and the centroid's mean speed; the faults started,
    and the broadcasts offered to and heard by the agents.
    """
    row: dict[str, Any] = dict.fromkeys(METRICS)
    if analysis is None:
        return row
    mission = _phase(analysis, "mission")

    def extent(key: str, what: str) -> Any:
        value = mission.get(key)
        return value.get(what) if isinstance(value, dict) else None

    window = analysis.get("window")
    drifts = [d for d in analysis.get("drift", []) if d.get("error") is not None]
    faults = analysis.get("faults", [])
    summaries = [f["detail"] for f in faults if f["kind"] == "broadcast" and f["event"] == "summary"]
    row.update(
        agents=len(analysis.get("agents", [])),
        mission_s=(window["end"] - window["start"]) if window else None,
        radius_start=extent("radius", "start"),
        radius_end=extent("radius", "end"),
        radius_max=extent("radius", "max"),
        radius_mean=extent("radius", "mean"),
        mean_distance_mean=extent("mean_distance", "mean"),
        min_separation=extent("min_separation", "distance"),
        nn_median=extent("nearest_neighbour", "median"),
        polarisation_mean=extent("polarisation", "mean"),
        polarisation_end=extent("polarisation", "end"),
        connected_fraction=extent("connectivity", "connected_fraction"),
        cohesion_ratio=analysis.get("cohesion_ratio"),
        radius_below_after=extent("radius_below", "after"),
        radius_above_after=extent("radius_above", "after"),
        drift_error_deg=sum(abs(d["error"]) for d in drifts) / len(drifts) if drifts else None,
        drift_speed=sum(d["speed"] for d in drifts) / len(drifts) if drifts else None,
        faults=sum(1 for f in faults if f["event"] == "start" and f["kind"] != "mission"),
        broadcast_offered=sum(int(s["offered"]) for s in summaries) if summaries else None,
        broadcast_heard=sum(int(s["heard"]) for s in summaries) if summaries else None,
    )
    return row


class ResultsTable:
    """``results.csv`` and ``results.json``, rewritten whole after each row (a temporary file renamed
    over the old one): a reader, or an interrupted sweep, always finds a complete table."""

    def __init__(self, folder: Path, cols: list[str]) -> None:
        self.csv = folder / "results.csv"
        self.json = folder / "results.json"
        self.columns = cols
        self.rows: list[dict[str, Any]] = []

    def add(self, row: dict[str, Any]) -> None:
        self.rows.append({c: row.get(c) for c in self.columns})
        self.rows.sort(key=lambda r: int(r["run"]))
        self.write()

    def write(self) -> None:
        tmp = self.csv.with_suffix(".csv.tmp")
        with tmp.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=self.columns)
            writer.writeheader()
            for row in self.rows:
                writer.writerow({k: _cell(v) for k, v in row.items()})
        tmp.replace(self.csv)
        tmp = self.json.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(self.rows, indent=1) + "\n", encoding="utf-8")
        tmp.replace(self.json)


def _cell(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "" if value is None else value


# ----------------------------------------------------------------------------- progress
class Progress:
    """A bar redrawn in place on a terminal; one plain line per finished run otherwise (CI logs)."""

    def __init__(self, total: int, stream: IO[str], tty: bool | None = None) -> None:
        self.total = total
        self.stream = stream
        self.tty = stream.isatty() if tty is None else tty
        self.done = 0
        self.failed = 0
        self.start = time.monotonic()

    def ended(self, row: dict[str, Any], label: str) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        what = "ok" if row["status"] == "ok" else f"{row['status']}: {row['reason']}"
        line = f"sweep: {self.done}/{self.total} run {row['run']} ({label}) {what} in {row['wall_s']:.1f} s"
        if not self.tty:
            print(line, file=self.stream, flush=True)
        elif row["status"] != "ok":  # above the bar, which the next draw puts back
            self.stream.write("\r" + line + "\x1b[K\n")
            self.stream.flush()

    def draw(self, running: int = 0) -> None:
        if not self.tty:
            return
        width = 30
        filled = int(width * self.done / self.total) if self.total else width
        elapsed = time.monotonic() - self.start
        eta = elapsed / self.done * (self.total - self.done) if self.done else None
        bar = "#" * filled + "." * (width - filled)
        text = f"\r[{bar}] {self.done}/{self.total} runs, {running} running, {self.failed} failed, {_mmss(elapsed)}"
        text += f" (about {_mmss(eta)} to go)" if eta is not None else ""
        self.stream.write(text + "\x1b[K")
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def count(n: int, what: str) -> str:
    return f"{n} {what}" + ("" if n == 1 else "s")


def _mmss(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 60}:{s % 60:02d}"


__all__ = ["HEAD", "METRICS", "TAIL", "Progress", "ResultsTable", "columns", "count", "metrics_row"]
