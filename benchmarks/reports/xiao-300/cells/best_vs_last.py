"""The best-vs-last table of ../cells.md: the xiao profile's "final start" runs, each tested at its best-by-validation
and at its last (300th epoch) checkpoint, with the Acceleration evaluator (accel_mse) beside the rollout metrics.

    cd benchmarks/reports/xiao-300/cells      # OMP_NUM_THREADS=1, the repository's python (encons importable)
    nice -n 5 python best_vs_last.py OUT      # OUT outside the work tree; rerun to resume

The runs are ``python -m encons.benchmark profile=xiao``'s runs of the seven cells below (seed 0, 300 epochs, the
profile's protocol), with the two settings the profile had when the final start was trained and has dropped since
(conf/profile/xiao.yaml's comment): the best checkpoint is kept (``callbacks.best``, monitored on
``val/traj_rel_err``) and every epoch validates by rollout (``validation.criterion=rollout``, the default). They are
planned by the benchmark runner's own ``encons.tools.benchmark.expand`` from ``profile=xiao`` and
``only=[...]``, the profile's ``~callbacks.best`` and ``validation.criterion=none`` taken out of their overrides, and
trained by its ``run_one`` into ``OUT/runs/<id>/`` (a finished run, one with ``result.json``, is skipped).

Each finished run is tested at ``best`` by its own training (``runs.train`` tests the best checkpoint:
``OUT/runs/<id>/test_metrics.json``) and evaluated at ``last`` (``last.ckpt``, written at the end of every epoch: the
300th epoch's weights) by ``encons.evaluate(run_dir, ckpt="last")``, the Python API of ``python -m encons.evaluate RUN
ckpt=last``, which writes ``OUT/runs/<id>/evaluation/``. Both are kept in ``OUT/eval/<id>-<ckpt>.json`` (a rerun
skips them). Then ``best_vs_last.json`` beside this script: per cell accel_mse, state MSE and energy MSE at
best and last, the best epoch (from 1, as the log counts), the run's training wall time and logged training loss
over epochs 201–300, the command, code commit, date and machine load. The table
is printed in ../cells.md's format.
"""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[3]

CELLS = [  # (system, label) in ../cells.md's order
    ("compound_pendulum", "glnn-h200-d4"),
    ("compound_pendulum", "second_order-h200-d3"),
    ("damped_oscillator", "glnn-h50-d3"),
    ("damped_oscillator", "glnn-h100-d3"),
    ("damped_oscillator", "glnn-h200-d3"),
    ("damped_oscillator", "glnn-h400-d3"),
    ("damped_oscillator", "second_order-h200-d3"),
]
TRAIN_ORDER = [0, 1, 6, 2, 3, 4, 5]  # the compound cells first (the diagnostics of diag.py need them)
DROPPED = ("~callbacks.best", "validation.criterion=none")  # the profile's since the final start
METRICS = ("accel_mse", "state_mse_raw", "energy_mse")  # state_mse_raw: the plain mean, as the file's old table
STAMP = re.compile(r"^\[(\d{4}-\d\d-\d\d \d\d:\d\d):\d\d,\d+\]", re.M)
LOSS_LINE = re.compile(r"epoch (\d+) of \d+ \(step \d+\): train/loss ([0-9.eE+-]+)")


def git_commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    dirty = subprocess.run(["git", "status", "--porcelain", "encons", "conf"], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def planned_runs() -> list:
    """The profile's runs of CELLS, seed 0, with the final start's checkpoint and validation settings."""
    from encons.tools.benchmark import expand
    from encons.training.build import compose

    only = "only=[" + ",".join(f"{s}/{label}" for s, label in CELLS) + "]"
    runs = expand(compose(["profile=xiao", only], config_name="benchmark"))
    for run in runs:
        missing = [o for o in DROPPED if o not in run.overrides]
        if missing:
            raise SystemExit(f"{run.id}: the profile no longer has {missing}; update DROPPED")
        run.overrides = [o for o in run.overrides if o not in DROPPED]
    by_cell = {(r.system, r.label): r for r in runs}
    return [by_cell[c] for c in CELLS]


def train(runs: list, out: Path) -> None:
    from encons.tools.benchmark import finished, run_one

    for k in TRAIN_ORDER:
        run = runs[k]
        if finished(run, out).exists():
            print(f"trained already: {run.id}", flush=True)
            continue
        print(f"training {run.id}: {' '.join(run.overrides)}  (load {os.getloadavg()[0]:.1f})", flush=True)
        row = run_one(run, out, str(out / "cache"))
        print(f"  {run.id}: {row.get('wall_time_s', 0):.0f} s, error {row.get('error') or 'none'}", flush=True)


def evaluated(run, out: Path, ckpt: str) -> dict:
    """The run's test metrics at checkpoint ``ckpt`` (cached in OUT/eval)."""
    import encons
    from encons.infra import checkpoints

    file = out / "eval" / f"{run.id}-{ckpt}.json"
    if file.exists():
        return json.loads(file.read_text())
    run_dir = out / "runs" / run.id
    ckpt_file = checkpoints.find(run_dir, ckpt)
    load = os.getloadavg()[0]
    started = time.perf_counter()
    if ckpt == "best":  # the run's own test: runs.train tests the best checkpoint, by the same evaluation
        how = "the run's own test (test_metrics.json: runs.train tests the best checkpoint)"
        metrics = json.loads((run_dir / "test_metrics.json").read_text())
    else:
        how = f"encons.evaluate(run, ckpt={ckpt!r}), i.e. python -m encons.evaluate RUN ckpt={ckpt}"
        metrics = encons.evaluate(run_dir, ckpt=ckpt)
    record = {
        "checkpoint": str(ckpt_file.relative_to(out)),
        "epoch": int(checkpoints.read(ckpt_file)["epoch"]) + 1,
        "tested_by": how,
        "wall_s": round(time.perf_counter() - started, 1),
        "load_1min": [round(load, 2), round(os.getloadavg()[0], 2)],
        "metrics": {k.removeprefix("test/"): v for k, v in metrics.items()},
    }
    file.parent.mkdir(parents=True, exist_ok=True)
    file.write_text(json.dumps(record, indent=1) + "\n")
    return record


def train_losses(run_dir: Path) -> dict[int, float]:
    """The logged train/loss of every epoch (train.log's epoch lines), by epoch from 1."""
    return {int(m[1]): float(m[2]) for m in LOSS_LINE.finditer((run_dir / "train.log").read_text())}


def cell_row(run, out: Path) -> dict:
    result = json.loads((out / "runs" / run.id / "result.json").read_text())
    best, last = evaluated(run, out, "best"), evaluated(run, out, "last")
    losses = train_losses(out / "runs" / run.id)
    late = [v for k, v in losses.items() if k > 200]
    stamps = STAMP.findall((out / "runs" / run.id / "train.log").read_text())
    return {
        "cell": f"{run.system} {run.label}",
        "run": f"runs/{run.id}",
        "paper_accel_mse": run.paper.get("accel_mse"),
        "best_epoch": best["epoch"],
        "last_epoch": last["epoch"],
        **{f"{m}_best": best["metrics"].get(m) for m in METRICS},
        **{f"{m}_last": last["metrics"].get(m) for m in METRICS},
        "train_wall_s": result.get("wall_time_s"),
        "trained_utc": [stamps[0], stamps[-1]] if stamps else None,  # train.log's first and last line
        "train_loss_epochs_201_300_min_max": [min(late), max(late)] if late else None,
        "error": result.get("error", ""),
        "tested_by": {"best": best["tested_by"], "last": last["tested_by"]},
        "eval_wall_s": {"best": best["wall_s"], "last": last["wall_s"]},
        "eval_load_1min": {"best": best["load_1min"], "last": last["load_1min"]},
        "best_metrics": best["metrics"],
        "last_metrics": last["metrics"],
    }


def fmt(x: float | None, paper: bool = False) -> str:
    if x is None:
        return "–"
    return f"{x:.2g}" if paper or abs(x) >= 1e-3 else f"{x:.1e}"


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    out = Path(sys.argv[1]).resolve()
    started, load0 = datetime.now(timezone.utc), os.getloadavg()
    runs = planned_runs()
    train(runs, out)
    rows = [cell_row(run, out) for run in runs]
    result = {
        "what": "../cells.md, 'The cells': best-by-validation vs last (epoch 300) checkpoint of the xiao profile's "
        "final-start runs, seed 0 (best_vs_last.py)",
        "command": "cd benchmarks/reports/xiao-300/cells && OMP_NUM_THREADS=1 nice -n 5 python best_vs_last.py OUT",
        "out": out.name,
        "code_commit": git_commit(),
        "date_utc": started.strftime("%Y-%m-%d %H:%M"),  # of this invocation; each run's: trained_utc
        "machine": f"{os.cpu_count()} CPU cores ({platform.machine()}), shared; OMP_NUM_THREADS="
        f"{os.environ.get('OMP_NUM_THREADS')}",
        "load_1min": {"start": round(load0[0], 2), "end": round(os.getloadavg()[0], 2)},
        "train_overrides": {r.id: r.overrides for r in runs},
        "dropped_from_profile": list(DROPPED),
        "best": "lowest val/traj_rel_err (callbacks.best), tested by the run's own test at the end of training",
        "last": "last.ckpt: the weights after the 300th epoch",
        "cells": rows,
    }
    (HERE / "best_vs_last.json").write_text(json.dumps(result, indent=1) + "\n")
    print("| cell | paper | accel_mse best / last | state MSE best / last | energy MSE best / last | best epoch |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        cols = [" / ".join(fmt(r[f"{m}_{c}"]) for c in ("best", "last")) for m in METRICS]
        print(f"| {r['cell']} | {fmt(r['paper_accel_mse'], paper=True)} | {' | '.join(cols)} | {r['best_epoch']} |")
    print(f"wrote {HERE / 'best_vs_last.json'}")


if __name__ == "__main__":
    main()
