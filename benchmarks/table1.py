"""Lim & Kasim (2023) Table 1 at a CPU-feasible budget: energy-deviation RMSE of test rollouts.

Every run trains with the paper's derivative objective (eq. (2), exact simulator derivatives,
noise σ = 0.1 on the states of Tasks 1, 2, 4) on the paper's data (conf/system/*.yaml), then
rolls out 100 fresh initial conditions to t = 100 and reports the median [2.5th, 97.5th
percentile] over trajectories of the RMSE of E(ŝ_t) − E(s_t), with the trajectory relative
error (Σ over the first 4 steps). Regulariser weights are the paper's, rescaled to encons' sums by
``encons.regularisers.from_paper_weight`` (w / 2n for C_H, w for C_D).

    python benchmarks/table1.py [--epochs 20] [--hidden 200] [--tasks 1 2 3 4] [--n-train-double 200]
        [--threads 1] [--out benchmarks/results/table1] [any train override ...]

On a shared machine ``--threads 1`` ran the whole table several times faster than torch's default.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch
from rich.console import Console
from rich.table import Table

from hydra.utils import execution_whitelist

from encons import api
from encons.benchmark import Progress, write_csv
from encons.errors import EnconsError

# (task, system, label, overrides, the paper's regulariser weight (Lim & Kasim §4.1), paper's median RMSE)
RUNS = [
    (1, "mass_spring", "NODE", ["model=node"], None, "0.086"),
    (1, "mass_spring", "NODE + C_H (ours)", ["model=node", "regulariser=hamiltonian"], 1e5, "0.0017"),
    (1, "mass_spring", "HNN", ["model=hnn"], None, "0.0065"),
    (1, "mass_spring", "LNN", ["model=lnn"], None, "0.0060"),
    (1, "mass_spring", "NSF", ["model=nsf"], None, "0.014"),
    (2, "pendulum", "NODE", ["model=node"], None, "∞"),
    (2, "pendulum", "NODE + C_H (ours)", ["model=node", "regulariser=hamiltonian"], 1e4, "0.024"),
    (2, "pendulum", "HNN", ["model=hnn"], None, "0.015"),
    (2, "pendulum", "LNN", ["model=lnn"], None, "0.032"),
    (2, "pendulum", "NSF", ["model=nsf"], None, "0.027"),
    (3, "double_pendulum", "NODE", ["model=node"], None, "∞"),
    (3, "double_pendulum", "INN-NODE + C_H' (ours)", ["model=inn_node", "regulariser=hamiltonian"], 1e3, "4.03"),
    (4, "damped_pendulum", "NODE", ["model=node"], None, "0.18"),
    (4, "damped_pendulum", "NODE + C_D (ours)", ["model=node", "regulariser=dissipative"], 1e2, "0.12"),
]


def regulariser_weight(overrides: list[str], paper_weight: float, cfg) -> list[str]:
    """``regulariser.weight`` equivalent to the paper's (``from_paper_weight``, on the system's state size)."""
    from encons.config import build_system
    from encons.regularisers import from_paper_weight

    constraint = next(o.split("=", 1)[1] for o in overrides if o.startswith("regulariser="))
    with execution_whitelist(api.trusted_targets()):
        system = build_system(cfg)
    weight = from_paper_weight(paper_weight, constraint, 2 * system.coord_dim(system.base_chart))
    return [f"regulariser.weight={weight:g}"]


def available(overrides: list[str]) -> bool:
    """Whether the ``model=`` config of a run is in the catalogue (``conf/model``)."""
    return next(o.split("=", 1)[1] for o in overrides if o.startswith("model=")) in api.catalogue("model")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--hidden", type=int, default=200, help="width of every MLP (paper: 200)")
    parser.add_argument("--batch-size", type=int, default=8, help="whole trajectories per batch")
    parser.add_argument("--n-train-double", type=int, default=200, help="double-pendulum trajectories (paper: 2000)")
    parser.add_argument("--tasks", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--out", default="benchmarks/results/table1")
    args, extra = parser.parse_known_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    os.environ.setdefault("WANDB_MODE", "disabled")
    api.quiet_upstream()

    out = Path(args.out)
    common = ["logger=none", "objective=derivative", f"trainer.max_epochs={args.epochs}", "optim.lr=1e-3",
              "model.depth=2", f"model.hidden={args.hidden}", f"data.batch_size={args.batch_size}"]
    todo = [run for run in RUNS if run[0] in args.tasks and available(run[3])]
    progress = Progress(len(todo), "table 1 run")
    rows = []
    for task, system, label, overrides, paper_weight, paper in todo:
        progress.start(f"task {task}: {label}")
        per_system = [f"data.chunk_len={300 if system == 'double_pendulum' else 30}"]
        if system == "double_pendulum":
            per_system.append(f"data.n_train={args.n_train_double}")
        run_dir = out / "runs" / f"task{task}-{label.split()[0].lower()}{'-reg' if '+' in label else ''}"
        overrides = [f"system={system}", *overrides, *common, *per_system]
        cfg = api.compose(*overrides, *extra, output_dir=run_dir, cache_dir=out / "cache")
        if paper_weight is not None:
            overrides += regulariser_weight(overrides, paper_weight, cfg)
            cfg = api.compose(*overrides, *extra, output_dir=run_dir, cache_dir=out / "cache")
        started = time.perf_counter()
        try:
            results, error = api.train(cfg).metrics, ""
        except EnconsError as err:
            results, error = {}, str(err)
        rows.append({"task": task, "system": system, "model": label, "paper_median": paper, "error": error,
                     "wall_time_s": time.perf_counter() - started, "overrides": " ".join(overrides[1:]),
                     **{k.removeprefix("test/"): v for k, v in results.items() if k.startswith("test/")}})
        write_csv(out / "table1.csv", rows)
    progress.done()
    print_table(rows, args)
    print(f"CSV: {out / 'table1.csv'}")


def print_table(rows: list[dict], args: argparse.Namespace) -> None:
    table = Table(title=f"Lim & Kasim Table 1 at {args.epochs} epochs, width {args.hidden} "
                        "(energy-deviation RMSE: median [2.5%, 97.5%])")
    for col in ("task", "system", "model", "energy RMSE", "paper median", "traj rel err (T=4)", "time [s]"):
        table.add_column(col)
    for r in rows:
        energy = (f"{r['energy_rmse_median']:.3g} [{r['energy_rmse_p2_5']:.2g}, {r['energy_rmse_p97_5']:.2g}]"
                  if "energy_rmse_median" in r else f"failed: {r['error'][:60]}")
        tre = f"{r['traj_rel_err']:.3g}" if "traj_rel_err" in r else "-"
        table.add_row(str(r["task"]), r["system"], r["model"], energy, r["paper_median"], tre,
                      f"{r['wall_time_s']:.0f}")
    Console(width=160).print(table)


if __name__ == "__main__":
    main()
