"""Plot a metric of an ``antalate sweep`` table against one parameter, one line per value of another,
each point the mean over the seeds with its standard deviation as an error bar.

    python examples/sweep/plot_sweep.py sweep-results/results.csv \\
        --x script.broadcast.reception --lines behavior.dovrat_swarm.sharp_turn_rate \\
        --metric radius_max -o sweep.png

Needs only matplotlib (``pip install 'antalate[plot]'``); failed runs are left out.
"""

from __future__ import annotations

import argparse
import csv
import statistics
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("table", help="results.csv of antalate sweep")
    ap.add_argument("--x", required=True, help="the parameter on the x axis (a column of the table)")
    ap.add_argument("--lines", help="the parameter that makes one line per value")
    ap.add_argument("--metric", default="radius_max", help="the column on the y axis (default radius_max)")
    ap.add_argument("-o", "--output", default="sweep.png")
    args = ap.parse_args()

    with open(args.table, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["status"] == "ok" and r[args.metric] != ""]
    groups: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        groups[r[args.lines] if args.lines else ""][float(r[args.x])].append(float(r[args.metric]))

    fig, ax = plt.subplots(figsize=(6, 4))
    for line, points in sorted(groups.items()):
        xs = sorted(points)
        means = [statistics.mean(points[x]) for x in xs]
        stds = [statistics.stdev(points[x]) if len(points[x]) > 1 else 0.0 for x in xs]
        ax.errorbar(
            xs, means, yerr=stds, marker="o", capsize=4, label=f"{args.lines} = {line}" if line else None
        )
    ax.set_xlabel(args.x)
    ax.set_ylabel(f"{args.metric} (mean ± sd over seeds)")
    if args.lines:
        ax.legend()
    fig.tight_layout()
    fig.savefig(args.output, dpi=100)
    print(f"{args.output}: {args.metric} of {len(rows)} runs")


if __name__ == "__main__":
    main()
