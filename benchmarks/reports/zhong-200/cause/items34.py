"""Items 3 and 4 of ``benchmarks/reports/zhong-200/cause.md``: the zhong-200 runs re-made with a per-step training log,
their tested checkpoints re-scored in both charts (item 3), and their training and validation curves (item 4).

    python benchmarks/reports/zhong-200/cause/items34.py OUT [--no-train] [--boot 10000] [--seed 0]

1. Trains (unless ``--no-train``) the six 2-pendulum runs of zhong-200 — ``../README.md``'s command with
   ``logger=csv`` added, ``out=OUT``, ``cache_dir=OUT/cache`` — through ``python -m encons.benchmark``; a rerun skips
   finished runs. Each run's ``test/traj_rel_err`` is set beside ``../summary.csv``'s (the runs of that file,
   whose folders were not kept; commit 1b2a5b3's code): on the same data (the baselines' and the oracle's figures
   equal) the relative difference says how far today's code re-makes them.
2. Item 3: each run's tested (best) checkpoint back with ``encons.load``, its test rollouts made as the test makes
   them (``module.observe``, ``module.predict(batch, states, module.evaluation)``) and scored per trajectory by
   ``encons.numerics.metrics.trajectory_relative_error`` (T = the run's horizon) in the Cartesian chart (the
   system's common chart, the test's; the mean must equal the run's test/traj_rel_err) and in the angle chart
   (q, q̇), angles compared as the system declares them (``System.angle_entries``; the 2-pendulum declares none,
   so the plain difference of its continuous angles); and in the Cartesian chart on the positions alone
   and on the velocities alone. Per pair (plain, angle-aware): the share of the test trajectories on which the angle
   form is worse, the mean per-trajectory difference (angle − plain) and its bootstrap 95 % interval (resampling
   trajectories, ``--boot`` draws, numpy seed ``--seed``).
3. Item 4: from each run's ``csv/version_0/metrics.csv`` (one row a training step, one a validation) the training
   loss (the L1 rollout loss on the training windows, the mean over the epoch's steps) and the validation
   ``val/traj_rel_err`` and ``val/loss`` after epochs 40, 100 and 200 (counted from 1, as ``train.log``), and the
   epoch of the best validation error (the tested checkpoint's).

Writes ``items34.json`` beside this script (paths relative to OUT) and prints the figures.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

import encons
from encons.numerics import metrics

HERE = Path(__file__).resolve().parent
REPORT = HERE.parent
PAIRS = {"HNN": ("hnn", "hnn_angle"), "HNN-structure": ("hnn_structure", "hnn_structure_angle")}
PAIRS["LNN-structure"] = ("lnn_structure", "lnn_structure_angle")
MODELS = [m for pair in PAIRS.values() for m in pair]
EPOCHS = (40, 100, 200)


def benchmark_command(out: Path) -> list[str]:
    """``../README.md``'s command with a per-step CSV log, into OUT."""
    only = ",".join(f"pendulum2/{m}" for m in MODELS)
    return [
        sys.executable,
        "-m",
        "encons.benchmark",
        "profile=zhong",
        "seeds=[0]",
        "n_train=[]",
        "threads=1",
        'train=["trainer.max_epochs=200","logger=csv"]',
        f"only=[{only}]",
        f"out={out}",
        f"cache_dir={out / 'cache'}",
    ]


def run_dir(out: Path, model: str) -> Path:
    return out / "runs" / f"pendulum2-{model}-seed0"


def recorded(key: str) -> dict[str, float]:
    """zhong-200's ``key`` of each model (``../summary.csv``)."""
    with open(REPORT / "summary.csv") as f:
        return {r["model"]: float(r[key]) for r in csv.DictReader(f) if r["model"] in MODELS}


@torch.no_grad()  # as the test runs (the fields take their own gradients); a kept graph fills the memory
def rollouts(path: Path) -> tuple[dict, dict[str, torch.Tensor]]:
    """The run's tested checkpoint and its test rollouts and truths, (N, T, D) in the model's chart."""
    run = encons.load(path)
    module, data = run.module, run.data
    data.setup("test")
    preds, trues = [], []
    for batch in data.test_dataloader():
        x, states = module.observe(batch)
        preds.append(module.predict(batch, states, module.evaluation).detach().double())
        trues.append(x.detach().double())
    pred, true = torch.cat(preds), torch.cat(trues)
    system, chart = module.system, module.model.chart
    charts = {}
    for name in ("cartesian", "angle"):
        charts[name] = (system.to_chart(pred, chart, name), system.to_chart(true, chart, name))
    info = {
        "checkpoint": str(run.checkpoint.relative_to(path.parent.parent)) if run.checkpoint else None,
        "model_chart": chart,
        "common_chart": system.common_chart,
        "horizon": module.horizon,
        "trajectories": len(true),
    }
    angles = {name: system.angle_entries(name) for name in charts}
    return info, {"charts": charts, "angles": angles, "horizon": module.horizon}


def per_trajectory(r: dict) -> dict[str, np.ndarray]:
    """traj_rel_err per test trajectory: Cartesian, angle chart, Cartesian positions only, velocities only."""
    h = r["horizon"]
    (pc, tc), (pa, ta) = r["charts"]["cartesian"], r["charts"]["angle"]
    half = pc.shape[-1] // 2
    tre = metrics.trajectory_relative_error
    return {
        "cartesian": tre(pc, tc, h, r["angles"]["cartesian"]).numpy(),
        "angle": tre(pa, ta, h, r["angles"]["angle"]).numpy(),
        "cartesian_positions": tre(pc[..., :half], tc[..., :half], h).numpy(),
        "cartesian_velocities": tre(pc[..., half:], tc[..., half:], h).numpy(),
    }


def paired(plain: np.ndarray, angle: np.ndarray, boot: int, seed: int) -> dict:
    """Angle form against plain form over the same test trajectories."""
    diff = angle - plain
    rng = np.random.default_rng(seed)
    means = diff[rng.integers(0, len(diff), (boot, len(diff)))].mean(1)
    lo, hi = np.quantile(means, [0.025, 0.975])
    return {
        "angle_worse_share": float((diff > 0).mean()),
        "mean_difference": float(diff.mean()),
        "bootstrap_95": [float(lo), float(hi)],
    }


def curves(path: Path) -> dict:
    """Training loss (epoch mean of the step losses) and validation figures after EPOCHS (1-based)."""
    with open(path / "csv" / "version_0" / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    train: dict[int, list[float]] = {}
    val: dict[int, dict[str, float]] = {}
    for r in rows:
        epoch = int(r["epoch"]) + 1
        if r.get("train/loss"):
            train.setdefault(epoch, []).append(float(r["train/loss"]))
        if r.get("val/traj_rel_err"):
            val[epoch] = {"val_traj_rel_err": float(r["val/traj_rel_err"]), "val_loss": float(r["val/loss"])}
    best = min(val, key=lambda e: val[e]["val_traj_rel_err"])
    return {
        "epochs": {
            str(e): {"train_loss": float(np.mean(train[e])), **val[e]} for e in EPOCHS if e in train and e in val
        },
        "best_val_epoch": best,
        "best_val_traj_rel_err": val[best]["val_traj_rel_err"],
        "val_traj_rel_err_min_last_20": min(val[e]["val_traj_rel_err"] for e in val if e > max(val) - 20),
        "val_traj_rel_err_min_epochs_161_180": min(val[e]["val_traj_rel_err"] for e in val if 160 < e <= 180),
    }


def commit() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True).stdout
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "."], cwd=HERE, capture_output=True, text=True)
        return sha.strip() + (" (script dirty)" if dirty.stdout.strip() else "")
    except OSError:
        return "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--no-train", action="store_true")
    ap.add_argument("--boot", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    out = args.out.resolve()
    started, load = time.time(), os.getloadavg()[0]
    if not args.no_train:
        subprocess.run(benchmark_command(out), check=True)
    old, old_baseline = recorded("test/traj_rel_err"), recorded("test/baseline_constant/traj_rel_err")
    runs: dict[str, dict] = {}
    scores: dict[str, dict[str, np.ndarray]] = {}
    for model in MODELS:
        path = run_dir(out, model)
        row = json.loads((path / "result.json").read_text())
        info, r = rollouts(path)
        scores[model] = per_trajectory(r)
        runs[model] = {
            "run": str(path.relative_to(out)),
            **info,
            "test_traj_rel_err": row["test/traj_rel_err"],
            "zhong200_summary_traj_rel_err": old[model],
            "relative_difference_to_zhong200": row["test/traj_rel_err"] / old[model] - 1,
            "same_data_as_zhong200": row["test/baseline_constant/traj_rel_err"] == old_baseline[model],
            "wall_time_s": row.get("wall_time_s"),
            "rescored": {k: float(v.mean()) for k, v in scores[model].items()},
            "curves": curves(path),
        }
        runs[model]["rescored_equals_test"] = (
            abs(runs[model]["rescored"]["cartesian"] - row["test/traj_rel_err"]) < 1e-6
        )
    pairs = {}
    for label, (plain, angle) in PAIRS.items():
        pairs[label] = {
            "plain": plain,
            "angle": angle,
            **{
                chart: {
                    "plain": runs[plain]["rescored"][chart],
                    "angle": runs[angle]["rescored"][chart],
                    **paired(scores[plain][chart], scores[angle][chart], args.boot, args.seed),
                }
                for chart in ("cartesian", "angle", "cartesian_positions", "cartesian_velocities")
            },
        }
    result = {
        "command": " ".join(
            ["python benchmarks/reports/zhong-200/cause/items34.py OUT", *(["--no-train"] if args.no_train else [])]
        )
        + f" --boot {args.boot} --seed {args.seed}",
        "benchmark_command": " ".join(["python", *benchmark_command(Path("OUT"))[1:]]),
        "commit": commit(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "load_1min_at_start_and_end": [round(load, 2), round(os.getloadavg()[0], 2)],
        "wall_s": None,
        "torch": torch.__version__,
        "metric": "traj_rel_err per test trajectory, t = 0..horizon (encons.numerics.metrics), means over "
        "trajectories; angle chart: no declared angles on the 2-pendulum, so plain differences",
        "train_loss": "L1 rollout loss on the training windows (module.rollout_loss), mean of the epoch's steps",
        "runs": runs,
        "pairs": pairs,
    }
    result["wall_s"] = round(time.time() - started, 1)
    (HERE / "items34.json").write_text(json.dumps(result, indent=1) + "\n")
    for model, r in runs.items():
        print(
            f"{model:22s} test {r['test_traj_rel_err']:.4g} (zhong-200 {r['zhong200_summary_traj_rel_err']:.4g}, "
            f"{100 * r['relative_difference_to_zhong200']:+.2f} %); rescored "
            + ", ".join(f"{k} {v:.4g}" for k, v in r["rescored"].items())
        )
        print(
            "    "
            + "; ".join(
                f"ep {e}: train {c['train_loss']:.4g} val {c['val_traj_rel_err']:.4g}"
                for e, c in r["curves"]["epochs"].items()
            )
            + f"; best val epoch {r['curves']['best_val_epoch']}"
        )
    for label, p in pairs.items():
        for chart in ("cartesian", "angle", "cartesian_positions", "cartesian_velocities"):
            c = p[chart]
            print(
                f"{label:14s} {chart:21s} plain {c['plain']:.4g} angle {c['angle']:.4g}; angle worse on "
                f"{100 * c['angle_worse_share']:.0f} %, mean diff {c['mean_difference']:.4g} "
                f"[{c['bootstrap_95'][0]:.4g}, {c['bootstrap_95'][1]:.4g}]"
            )


if __name__ == "__main__":
    main()
