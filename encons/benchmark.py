"""Benchmark grid: every model × system × seed trained on the same data, then tables and figures.

    python -m encons.benchmark systems=[pendulum2,gyroscope] models=[node,hnn_angle,chnn] seeds=[0,1] \\
        [out=benchmarks/results/NAME] [any train override, e.g. trainer.max_epochs=50]

``models=all`` / ``systems=all`` take every option of ``conf/model`` / ``conf/system``; a model a
system cannot serve (chart, constraints) fails with its one-line reason in ``results.csv``.
Each run prints ``benchmark run k of n (...), elapsed, ETA`` to stderr.

Writes ``results.csv`` (one row per run), ``summary.csv`` (mean ± std over seeds) and the papers'
comparison figures (trajectory relative error per model, Zhong et al. Fig. 2; relative error and
energy error vs time, Figs. 3–4) under ``out``, and prints the summary table.
"""

from __future__ import annotations

import csv
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

from omegaconf import OmegaConf
from rich.console import Console
from rich.table import Table

from encons import api
from encons.errors import EnconsError
from encons.report import Progress

GRID_KEYS = ("systems", "models", "seeds", "out")


def run_grid(systems: list[str], models: list[str], seeds: list[int], out: Path, overrides: list[str]) -> list[dict]:
    """Train every combination (the data of a system are shared: same data seed); one row each."""
    grid = [(system, model, seed) for system in systems for model in models for seed in seeds]
    progress = Progress(len(grid), "benchmark run")
    rows = []
    for system, model, seed in grid:
        run_dir = out / "runs" / f"{system}-{model}-seed{seed}"
        progress.start(f"{system} × {model} × seed {seed}")
        cfg = api.compose(f"system={system}", f"model={model}", f"seed={seed}", *overrides, output_dir=run_dir)
        try:
            results, error = api.train(cfg).metrics, ""
        except EnconsError as err:
            results, error = {}, str(err)
        rows.append({"system": system, "model": model, "seed": seed, "horizon": cfg.horizon,
                     "run_dir": str(run_dir), "error": error, **results})
    progress.done()
    return rows


def summarise(rows: list[dict], metrics: tuple[str, ...] = ("test/traj_rel_err", "test/energy_abs_err",
                                                             "wall_time_s")) -> list[dict]:
    """Mean and std over seeds per (system, model)."""
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for row in rows:
        groups[(row["system"], row["model"])].append(row)
    summary = []
    for (system, model), group in groups.items():
        entry = {"system": system, "model": model, "runs": len(group)}
        for key in metrics:
            values = [r[key] for r in group if key in r]
            if values:
                mean = sum(values) / len(values)
                entry[key] = mean
                entry[f"{key}_std"] = (sum((v - mean) ** 2 for v in values) / max(1, len(values) - 1)) ** 0.5
        summary.append(entry)
    return summary


def write_csv(path: Path, rows: list[dict]) -> None:
    keys = list(dict.fromkeys(k for row in rows for k in row))
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def print_table(summary: list[dict], horizon: int = 4) -> None:
    table = Table(title="encons benchmark (mean ± std over seeds)")
    for col in ("system", "model", f"traj rel err (T={horizon})", "energy abs err", "wall time [s]"):
        table.add_column(col)
    for e in summary:
        cell = lambda k: f"{e[k]:.3g} ± {e[k + '_std']:.2g}" if k in e else "failed"
        table.add_row(e["system"], e["model"], cell("test/traj_rel_err"), cell("test/energy_abs_err"),
                      cell("wall_time_s"))
    Console().print(table)


def main(argv: list[str] | None = None) -> None:
    from encons.plots import comparison_figures

    api.quiet_upstream()
    args = OmegaConf.from_dotlist([a for a in (argv or sys.argv[1:]) if a.split("=")[0] in GRID_KEYS])
    overrides = [a for a in (argv or sys.argv[1:]) if a.split("=")[0] not in GRID_KEYS]
    out = Path(args.get("out") or f"benchmarks/results/{time.strftime('%Y-%m-%d_%H-%M-%S')}")
    out.mkdir(parents=True, exist_ok=True)
    pick = lambda key, group, default: api.catalogue(group) if args.get(key) == "all" else list(args.get(key, default))
    rows = run_grid(pick("systems", "system", ["pendulum2"]), pick("models", "model", ["node", "hnn"]),
                    list(args.get("seeds", [0])), out, ["logger=none", *overrides])
    summary = summarise(rows)
    write_csv(out / "results.csv", rows)
    write_csv(out / "summary.csv", summary)
    (out / "overrides.json").write_text(json.dumps(overrides))
    horizon = rows[0]["horizon"] if rows else 4
    comparison_figures(rows, summary, out, horizon)
    print_table(summary, horizon)
    print(f"results: {out}")


if __name__ == "__main__":
    main()
