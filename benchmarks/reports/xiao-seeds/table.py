"""Xiao et al. Tables 3–4 over seeds: mean ± std per cell beside the paper's number.

    python benchmarks/reports/xiao-seeds/table.py OUT [OUT ...] > benchmarks/reports/xiao-seeds/seeds.md

Seed 0 is the committed epoch-300 evaluation (benchmarks/reports/xiao-300/epoch300/summary.csv, one run per
cell); the other seeds are every finished ``runs/*/result.json`` under the OUT folders of
``python -m encons.benchmark profile=xiao``. std is the sample standard deviation (n − 1) over the seeds there.
"""

from __future__ import annotations

import csv
import json
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
    with open(HERE.parent / "xiao-300/epoch300/summary.csv") as f:
        for row in csv.DictReader(f):
            if row["model"].startswith(("glnn", "second_order")):
                values.setdefault((row["system"], row["model"]), {})[0] = {m: float(row[f"test/{m}"]) for m in METRICS}
    walls: dict[tuple[str, str], list[float]] = {}
    for out in sys.argv[1:]:
        for path in sorted(Path(out).glob("runs/*/result.json")):
            r = json.loads(path.read_text())
            if r.get("error") or r["seed"] == 0:
                continue
            values.setdefault((r["system"], r["model"]), {})[r["seed"]] = {m: r[f"test/{m}"] for m in METRICS}
            walls.setdefault((r["system"], r["model"]), []).append(r["wall_time_s"])
    print("| system | cell | seeds | " + " | ".join(f"{m} mean ± std" for m in METRICS)
          + " | accel_mse per seed | paper | wall s (seeds ≥ 1) |")
    print("|---" * (6 + len(METRICS)) + "|")
    for system, label, paper in cells:
        per_seed = values.get((system, label), {})
        seeds = sorted(per_seed)
        cols = []
        for m in METRICS:
            xs = [per_seed[s][m] for s in seeds]
            cols.append("–" if not xs else f"{xs[0]:.3g}" if len(xs) == 1
                        else f"{statistics.mean(xs):.3g} ± {statistics.stdev(xs):.2g}")
        each = ", ".join(f"{s}: {per_seed[s]['accel_mse']:.2g}" for s in seeds) or "–"
        wall = ", ".join(f"{w:.0f}" for w in walls.get((system, label), [])) or "–"
        print(f"| {system} | {label} | {','.join(map(str, seeds)) or '–'} | " + " | ".join(cols)
              + f" | {each} | {paper if paper is not None else '–'} | {wall} |")


if __name__ == "__main__":
    main()
