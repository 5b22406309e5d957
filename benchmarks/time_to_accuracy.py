"""Time to accuracy: wall time until a default training run first reaches a fixed held-out error,
for the flagship (CHNN on the gyroscope) and one model per family (``make bench``).

What a user waits for, so schedule and speed changes are judged by it rather than by time per step.
Each run is ``encons.train``'s default for its model and system (data, optimiser, schedule, threads
by ``encons.infra.threads``) with ``trainer.max_epochs`` as the budget. The clock starts when ``fit``
starts (data generation is reported beside it) and stops at the first validation whose
``val/traj_rel_err`` (clean held-out trajectories, the test metric's definition) is at or below the
row's target; training stops there, and the test set scores those weights (``test traj_rel_err``).
A row that never reaches its target within the budget says so. Wall time includes validation and
whatever else the machine runs: state the load beside the table.
Usage: ``python benchmarks/time_to_accuracy.py [--runs chnn/gyroscope ...] [--max-epochs 100] [--out CSV]``.
"""

from __future__ import annotations

import argparse
import csv
import logging
import os
import tempfile
import time
import warnings
from pathlib import Path

import lightning.pytorch as pl
import torch

from encons.entry import api
from encons.infra.compat import quiet_upstream

#: model/system -> target val/traj_rel_err: the flagship, then one model per family on pendulum2
#: (about twice what each reached in 100 default epochs, sweeps/README.md)
RUNS = {
    "chnn/gyroscope": 0.005,
    "node/pendulum2": 0.4,
    "hnn_angle/pendulum2": 0.5,
    "lnn_structure/pendulum2": 0.3,
    "symo/pendulum2": 0.5,
    "glnn/pendulum2": 0.5,
}
FIELDS = [
    "model",
    "system",
    "target",
    "reached",
    "time_to_target_s",
    "epochs",
    "val_traj_rel_err",
    "test_traj_rel_err",
    "data_s",
    "threads",
]


class Clock(pl.Callback):
    """Stops training at the first validation whose ``monitor`` is at or below ``target``, noting
    the wall time since ``fit`` started and the epochs run."""

    def __init__(self, target: float, monitor: str = "val/traj_rel_err"):
        self.target, self.monitor = target, monitor
        self.start, self.reached_s, self.epochs, self.value = 0.0, None, 0, float("nan")

    def on_fit_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self.start = time.perf_counter()

    def on_validation_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self.epochs, self.value = trainer.current_epoch + 1, float(trainer.callback_metrics[self.monitor])
        if self.value <= self.target:
            self.reached_s = time.perf_counter() - self.start
            trainer.should_stop = True


def time_to_accuracy(
    model: str, system: str, target: float, max_epochs: int, workdir: Path, overrides: tuple[str, ...] = ()
) -> dict:
    """One row: train ``model`` on ``system`` until ``val/traj_rel_err`` ≤ ``target`` (or ``max_epochs``)."""
    cfg = api.compose(
        f"model={model}",
        f"system={system}",
        "logger=none",
        f"trainer.max_epochs={max_epochs}",
        "trainer.enable_progress_bar=false",
        "trainer.enable_model_summary=false",
        *overrides,
        output_dir=workdir / f"{model}-{system}",
        cache_dir=workdir / "cache",
    )
    start = time.perf_counter()
    data, module = api.build(cfg)
    data_s = time.perf_counter() - start
    trainer, _ = api.build_trainer(cfg)
    clock = Clock(target)
    trainer.callbacks.append(clock)
    trainer.fit(module, datamodule=data)
    trainer.test(module, datamodule=data, verbose=False)
    return {
        "model": model,
        "system": system,
        "target": target,
        "reached": clock.reached_s is not None,
        "time_to_target_s": clock.reached_s,
        "epochs": clock.epochs,
        "val_traj_rel_err": clock.value,
        "test_traj_rel_err": module.test_metrics["traj_rel_err"],
        "data_s": data_s,
        "threads": torch.get_num_threads(),
    }


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--runs", nargs="+", default=list(RUNS), choices=list(RUNS), metavar="MODEL/SYSTEM")
    parser.add_argument("--max-epochs", type=int, default=100, help="budget per run")
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: encons.infra.threads' policy)"
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/time_to_accuracy.csv"))
    parser.add_argument("overrides", nargs="*", help="train overrides for every run, e.g. data.n_train=200")
    args = parser.parse_args(argv)
    os.environ.setdefault("WANDB_MODE", "disabled")
    quiet_upstream()
    for name in ("lightning.pytorch", "lightning.fabric"):  # devices, stop reason: per run, not news
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r"hydra\.utils\.instantiate\(\) resolved")
    overrides = (f"threads={args.threads or 'null'}", *args.overrides)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for run in args.runs:
            model, system = run.split("/")
            rows.append(time_to_accuracy(model, system, RUNS[run], args.max_epochs, Path(tmp), overrides))
            r = rows[-1]
            reached = f"{r['time_to_target_s']:.1f} s" if r["reached"] else f"not reached in {args.max_epochs} epochs"
            print(
                f"{run}: val traj_rel_err ≤ {r['target']}: {reached} ({r['epochs']} epochs; data {r['data_s']:.1f} s; "
                f"test traj_rel_err {r['test_traj_rel_err']:.3g})",
                flush=True,
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    header = [
        "model",
        "system",
        "target val traj_rel_err",
        "time to target s",
        "epochs",
        "val traj_rel_err",
        "test traj_rel_err",
        "data s",
        "threads",
    ]
    lines = [
        [
            r["model"],
            r["system"],
            f"{r['target']:g}",
            f"{r['time_to_target_s']:.1f}" if r["reached"] else f"not in {args.max_epochs} epochs",
            str(r["epochs"]),
            f"{r['val_traj_rel_err']:.3g}",
            f"{r['test_traj_rel_err']:.3g}",
            f"{r['data_s']:.1f}",
            str(r["threads"]),
        ]
        for r in rows
    ]
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    table = [
        f"{os.cpu_count()} cores, {stamp}, overrides: {' '.join(args.overrides) or 'none'}.",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    args.out.with_suffix(".md").write_text("\n".join(table + ["| " + " | ".join(line) + " |" for line in lines]) + "\n")
    print(f"written: {args.out}, {args.out.with_suffix('.md')}")
    return rows


if __name__ == "__main__":
    main()
