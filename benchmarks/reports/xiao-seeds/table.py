"""Xiao et al. Tables 3–4 over seeds: mean ± std per cell beside the paper's number.

    python benchmarks/reports/xiao-seeds/table.py benchmarks/reports/xiao-300-seeds/results.csv [CSV ...] \\
        > benchmarks/reports/xiao-seeds/seeds.md

Each cell's seeds are its rows in the committed ``results.csv`` files named (written by ``python -m encons.benchmark
profile=xiao 'seeds=[0,1,2]'``; a later file's row of the same cell and seed replaces an earlier one's). A cell
with no row there shows seed 0 of the committed epoch-300 evaluation (``benchmarks/reports/xiao-300/epoch300/
summary.csv``, one run per cell), marked "(epoch300)". std is the sample standard deviation (n − 1).
"""

from __future__ import annotations

import csv
import statistics
import sys
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
METRICS = ("accel_mse", "state_mse", "energy_mse")


def main() -> None:
    profile = yaml.safe_load((HERE.parents[2] / "conf/profile/xiao.yaml").read_text())
    cells = [(r["system"], r["label"], r.get("paper", {}).get("accel_mse")) for r in profile["runs"]]
    values: dict[tuple[str, str], dict[int, dict[str, float]]] = {}
    walls: dict[tuple[str, str], set[float]] = {}
    for name in sys.argv[1:]:
        with open(name) as f:
            for row in csv.DictReader(f):
                if row.get("error"):
                    continue
                key = (row["system"], row["model"])
                values.setdefault(key, {})[int(row["seed"])] = {m: float(row[f"test/{m}"]) for m in METRICS}
                walls.setdefault(key, set()).add(round(float(row["wall_time_s"])))
    fallback: dict[tuple[str, str], dict[str, float]] = {}
    with open(HERE.parent / "xiao-300/epoch300/summary.csv") as f:
        for row in csv.DictReader(f):
            if row["model"].startswith(("glnn", "second_order")):  # the cells (the oracle row has no accel_mse)
                fallback[(row["system"], row["model"])] = {m: float(row[f"test/{m}"]) for m in METRICS}
    print(
        "| system | cell | seeds | "
        + " | ".join(f"{m} mean ± std" for m in METRICS)
        + " | accel_mse per seed | paper | wall s |"
    )
    print("|---" * (6 + len(METRICS)) + "|")
    for system, label, paper in cells:
        per_seed = values.get((system, label))
        source = ""
        if not per_seed and (system, label) in fallback:
            per_seed, source = {0: fallback[(system, label)]}, " (epoch300)"
        per_seed = per_seed or {}
        seeds = sorted(per_seed)
        cols = []
        for m in METRICS:
            xs = [per_seed[s][m] for s in seeds]
            cols.append(
                "–" if not xs else f"{xs[0]:.3g}" if len(xs) == 1 else f"{statistics.mean(xs):.3g} ± {statistics.stdev(xs):.2g}"
            )
        each = ", ".join(f"{s}: {per_seed[s]['accel_mse']:.2g}" for s in seeds) or "–"
        wall = ", ".join(f"{w:.0f}" for w in sorted(walls.get((system, label), set()))) or "–"
        print(
            f"| {system} | {label} | {','.join(map(str, seeds)) or '–'}{source} | "
            + " | ".join(cols)
            + f" | {each} | {paper if paper is not None else '–'} | {wall} |"
        )


if __name__ == "__main__":
    main()
