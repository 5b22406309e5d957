"""Summary tables: one run's metrics (also copied into its log file), progress lines, and a
benchmark's report rebuilt from its finished runs.

    python -m encons.report DIR     # DIR: a benchmark's output folder (it holds runs/*/result.json)
    python -m encons.report SWEEP   # SWEEP: a Hydra multirun folder (it holds multirun.yaml)
    python -m encons.report --docs  # the result tables of README.md and docs/ from benchmarks/reports/
                                    # (encons.tools.docs)

Writes ``results.csv`` (one row per run), ``summary.csv`` and ``summary.md`` (every test metric per
model × system, mean ± std over seeds, beside the paper's published value where the profile gives
one) and the papers' figures: trajectory relative error per model (Zhong et al. Fig. 2), relative
and energy error vs time (Figs. 3–4), data efficiency (Fig. 5, when the profile has ``n_train``
runs; with the §7 metrics also Santos et al. Figs. 3–4, ``santos_<system>.png``), state and energy MSE
vs time (Xiao et al. Figs. 3 and 5) and the energy-deviation RMSE median with 2.5–97.5 % bars (Lim &
Kasim Table 1). No training.

For a multirun folder: ``sweep.csv`` and ``sweep.md``, one row per job (the keys the sweep varied,
then every test metric of its ``test_metrics.json``; unfinished jobs are listed as such), and with
two varied keys one key × key table per headline metric (e.g. Xiao et al. Tables 3–4 from
``sweeps=glnn_size``).
"""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from rich.console import Console

from encons.infra.errors import ConfigError
from encons.training.results import mean_and_sd

if TYPE_CHECKING:
    from omegaconf import DictConfig
from encons.infra.io import atomic_open, write_text


def recorded(path: str | Path, out: str | Path) -> str:
    """``path`` as a report records it: relative to ``out`` (``.`` for ``out`` itself) when it lies inside, else
    its name alone, so a committed report holds none of the machine's absolute folders."""
    path, out = Path(path).absolute(), Path(out).absolute()
    return path.relative_to(out).as_posix() or "." if path.is_relative_to(out) else path.name


def recorded_override(override: str, out: str | Path) -> str:
    """A ``key=value`` override as a report records it: an absolute path value (``data.path=/scratch/x.npz``)
    ``recorded`` (relative to ``out``, else its name), every other override as it is."""
    key, sep, value = override.partition("=")
    return f"{key}={recorded(value, out)}" if sep and Path(value).is_absolute() else override


def portable_row(row: dict, out: str | Path) -> dict:
    """A result row with its ``run_dir`` recorded relative to ``out`` (``recorded``)."""
    return {**row, "run_dir": recorded(row["run_dir"], out)} if row.get("run_dir") else row


def load_rows(out: Path) -> list[dict]:
    """The rows of the finished runs under ``out/runs`` (sorted by run folder), each ``run_dir`` the folder
    its ``result.json`` lies in now (a moved or committed results folder still finds its curves; ``results.csv``
    records it relative to ``out``)."""
    allowed = "allowed: a benchmark's output folder (runs/*/result.json) or a Hydra multirun folder (multirun.yaml)"
    if not out.is_dir():
        raise ConfigError(f"folder={str(out)!r} {'is a file' if out.exists() else 'does not exist'}; {allowed}")
    files = sorted((out / "runs").glob("*/result.json"))
    if not files:
        raise ConfigError(f"folder={str(out)!r} holds no finished benchmark runs (no runs/*/result.json); {allowed}")
    rows = []
    for f in files:
        try:
            rows.append({**json.loads(f.read_text()), "run_dir": str(f.parent)})
        except ValueError as err:
            raise ConfigError(
                f"{str(f)!r} is not a result row ({err}); allowed: a result.json written by "
                f"encons.tools.benchmark (delete it and rerun the benchmark to redo that run)"
            ) from None
    return rows


def seed_summary(rows: list[dict]) -> list[dict]:
    """Mean and std over seeds of every metric per (system, model, n_train), in first-seen order."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for row in rows:
        groups[(row["system"], row["model"], row["n_train"], row.get("data_efficiency", False))].append(row)
    metrics = list(dict.fromkeys(k for row in rows for k in row if k.startswith("test/") or k == "wall_time_s"))
    summary = []
    for (system, model, n_train, efficiency), group in groups.items():
        entry = {
            "system": system,
            "model": model,
            "n_train": n_train,
            "data_efficiency": efficiency,
            "runs": len(group),
            "failed": sum(bool(r.get("error")) for r in group),
            "optimiser": " / ".join(dict.fromkeys(r["optimiser"] for r in group if r.get("optimiser"))),
        }
        for key in metrics:
            values = [r[key] for r in group if key in r and not r.get("error")]
            if values:
                entry[key], entry[f"{key}_sd"] = mean_and_sd(values)
        summary.append(entry)
    return summary + oracle_entries(rows)


ORACLE = "oracle (true field)"


def oracle_entries(rows: list[dict]) -> list[dict]:
    """One row per system: the true field scored by the runs' own evaluation (their ``test/oracle/*``, the
    same starts, integrator, horizon and metrics), mean and std over the runs (charts may differ)."""
    by_system: dict[str, list[dict]] = defaultdict(list)
    for row in rows:
        if not row.get("error") and not row.get("data_efficiency"):
            floor = {
                f"test/{k.removeprefix('test/oracle/')}": v for k, v in row.items() if k.startswith("test/oracle/")
            }
            if floor:
                by_system[row["system"]].append(floor)
    entries = []
    for system, floors in by_system.items():
        entry = {
            "system": system,
            "model": ORACLE,
            "n_train": "",
            "data_efficiency": False,
            "runs": len(floors),
            "failed": 0,
            "optimiser": "none (the true dynamics)",
        }
        for key in dict.fromkeys(k for f in floors for k in f):
            entry[key], entry[f"{key}_sd"] = mean_and_sd([f[key] for f in floors if key in f])
        entries.append(entry)
    return entries


def floor_notes(summary: list[dict], metric: str = "test/geom_rel_err") -> list[str]:
    """One line per system whose best model's ``metric`` is within 10× of the oracle's: the ranking there
    is close to what the evaluation itself can resolve."""
    notes = []
    for oracle in (e for e in summary if e["model"] == ORACLE and metric in e):
        models = [
            e
            for e in summary
            if e["system"] == oracle["system"]
            and e["model"] != ORACLE
            and not e["data_efficiency"]
            and math.isfinite(e.get(metric, math.nan))
        ]
        if models:
            best = min(models, key=lambda e: e[metric])
            if best[metric] <= 10 * oracle[metric]:
                notes.append(
                    f"{oracle['system']}: the best model ({best['model']}, {metric.removeprefix('test/')} "
                    f"{best[metric]:.3g}) is within 10× of the evaluation's floor (oracle {oracle[metric]:.3g})."
                )
    return notes


def published(out: Path) -> dict[str, dict]:
    """``"system/model" -> {metric: value}`` from the profile saved beside the runs."""
    from omegaconf import OmegaConf

    path = out / "benchmark.yaml"
    if not path.is_file():
        return {}
    cfg = cast("dict[str, Any]", OmegaConf.to_container(OmegaConf.load(path)))  # a YAML mapping: a dict
    paper = dict(cfg.get("paper") or {})
    for run in cfg.get("runs") or []:
        if run.get("paper"):
            paper[f"{run['system']}/{run['label']}"] = run["paper"]
    return paper


def write_csv(path: Path, rows: list[dict]) -> None:
    keys = list(dict.fromkeys(k for row in rows for k in row))
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


#: Where the headline metrics of encons' own evaluators, models and control tool stand in a summary's headline
#: table (the order of every report written so far). Which metrics a run shows is declared by what scored it
#: (``Evaluator.headline``, ``DynamicsModel.headline``, ``encons.tools.control.HEADLINE``) and recorded in its
#: result row; a declared metric not placed here follows these, in the order declared (``headline``).
ORDER = (
    "wall_time_s",
    "test/diverged",
    "test/traj_rel_err",
    "test/geom_rel_err",
    "test/vpt",
    "test/energy_abs_err",
    "test/energy_rmse_median",
    "test/state_mse",
    "test/state_mse_final",
    "test/energy_mse",
    "test/energy_mse_final",
    "test/accel_mse",
    "test/baseline_constant/state_mse_final",
    "test/baseline_linear_ode/state_mse_final",
    "test/mse_train",
    "test/mse_test",
    "test/mse_test_floor",
    "test/mse_integration",
    "test/energy_mse_integration",
    "test/mass_mse",
    "test/newton_unconverged",
    "test/newton_unconverged_integration",
    "test/pixel_mse",
    "test/pixel_mse_final",
    "test/pixel_mse_final_median",
    "test/baseline_constant/pixel_mse",
    "test/autoencoder/pixel_mse",
    "test/autoencoder/pixel_mse_final",
    "test/control/success_rate",
    "test/oracle/success_rate",
    "test/control/time_to_upright_s",
    "test/oracle/time_to_upright_s",
    "test/control/effort",
    "test/oracle/effort",
    "test/control/pred_rmse",
    "test/control/b_rel_err",
)


def headline(rows: list[dict]) -> list[str]:
    """The headline metrics of a summary of ``rows``: those each row records (``headline``: what its run's
    evaluators, model and tools declare, ``encons.tools.benchmark.declared_headline``; a row written before
    runs recorded them: ``ORDER``), those placed in ``ORDER`` at their place, the others after in first-seen order."""
    declared = dict.fromkeys(k for row in rows for k in row.get("headline", ORDER))
    return [m for m in ORDER if m in declared] + [m for m in declared if m not in ORDER]


def mean_sd(mean: float, sd: float, runs: int) -> str:
    """A cell "mean ± sd", or the mean alone where it is one run's value (no spread to give) or the spread is
    below float64 rounding of the mean (identical runs: 8.5e-18 beside 0.1 is no spread)."""
    if runs <= 1 or not sd > 1e-12 * abs(mean):  # NaN sd: a spread that cannot be told, so none
        return f"{mean:.3g}"
    return f"{mean:.3g} ± {sd:.2g}"


def markdown(
    summary: list[dict], paper: dict[str, dict], source: str = "", headline: Sequence[str] | bool = False
) -> str:
    """A Markdown table: model × system rows, metrics as mean ± std, paper values beside (a published value
    named as a metric right after that metric's column, the others at the end); every metric, or the
    ``headline`` ones the runs have (``True``: those of ``ORDER``), in its order."""
    metrics = list(
        dict.fromkeys(
            k for e in summary for k in e if (k.startswith("test/") or k == "wall_time_s") and not k.endswith("_sd")
        )
    )
    if headline:
        metrics = [m for m in (ORDER if headline is True else headline) if m in metrics]
    paper_keys = list(dict.fromkeys(m for values in paper.values() for m in values))
    columns: list[tuple[str | None, str | None]] = []  # (metric, None) or (None, published key)
    for m in metrics:
        columns.append((m, None))
        if m.removeprefix("test/") in paper_keys:
            columns.append((None, m.removeprefix("test/")))
    columns += [(None, k) for k in paper_keys if (None, k) not in columns]
    head = [
        "system",
        "model",
        "n_train",
        "runs",
        *[m.removeprefix("test/") if m else f"paper {k}" for m, k in columns],
        "optimiser",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in summary:
        cells = [e["system"], e["model"], str(e["n_train"]), f"{e['runs'] - e['failed']}/{e['runs']}"]
        values = paper.get(f"{e['system']}/{e['model']}", {}) if not e["data_efficiency"] else {}
        cells += [
            (
                mean_sd(e[m], e[m + "_sd"], e["runs"] - e["failed"])
                if m in e
                else "failed"
                if e["failed"] == e["runs"]
                else "—"
            )
            if m
            else f"{values[k]:.3g}"
            if k in values
            else ""
            for m, k in columns
        ]  # —: a metric this model does not report (plain_inverse, newton_unconverged)
        cells.append(e.get("optimiser", ""))
        lines.append("| " + " | ".join(cells) + " |")
    note = f"\nPublished values: {source}\n" if source and paper_keys else ""
    floors = floor_notes(summary)
    if floors:
        note += "\n" + "\n".join(floors) + "\n"
    return "\n".join(lines) + "\n" + note


def write_report(out: str | Path) -> list[Path]:
    """Tables and figures of the finished runs under ``out``; returns the files written."""
    from omegaconf import OmegaConf

    from encons.tools import figures

    out = Path(out)
    rows = load_rows(out)
    summary = seed_summary(rows)
    paper = published(out)
    source = ""
    if (out / "benchmark.yaml").is_file():
        source = cast("DictConfig", OmegaConf.load(out / "benchmark.yaml")).get("paper_source", "")  # a mapping
    shown = headline(rows)
    write_csv(out / "results.csv", [{k: v for k, v in portable_row(r, out).items() if k != "headline"} for r in rows])
    write_csv(
        out / "summary.csv",
        [{**e, **{f"paper {m}": v for m, v in paper.get(f"{e['system']}/{e['model']}", {}).items()}} for e in summary],
    )
    write_text(
        out / "summary.md",
        f"# {out.name}\n\n"
        + markdown(summary, paper, source, headline=shown)
        + "\n## Every metric\n\n"
        + markdown(summary, paper, source),
    )
    grid = [r for r in rows if not r.get("data_efficiency") and not r.get("error")]
    grid_summary = [e for e in summary if not e["data_efficiency"] and e["model"] != ORACLE]
    files = [out / "results.csv", out / "summary.csv", out / "summary.md"]
    if grid:
        files += figures.comparison_figures(grid, grid_summary, out)
        files += figures.energy_rmse_figure(grid_summary, paper, out)
        files += figures.control_success_figure(grid_summary, out)
    efficiency = [e for e in summary if e["data_efficiency"] and "test/traj_rel_err" in e]  # runs that finished
    if efficiency:
        files += figures.data_efficiency_figure(efficiency, out)
        files += figures.santos_figures(efficiency, out)
        files += figures.control_n_train_figure(efficiency, out)
    Console(width=200).print(markdown(summary, paper, source, headline=shown))
    return files


def _number(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text


def sweep_rows(out: Path) -> tuple[list[str], list[dict]]:
    """The keys a multirun varied and one row per job under ``out``: those keys' values (as given on
    the command line), ``job`` (its folder) and its ``test/...`` metrics (none if it did not finish)."""
    import yaml

    jobs = sorted(p.parent.parent for p in out.glob("**/.hydra/overrides.yaml") if p.parent.parent != out)
    if not jobs:
        raise ConfigError(
            f"folder={str(out)!r} holds no jobs of a multirun (no */.hydra/overrides.yaml); allowed: "
            f"the folder of a multirun (python -m encons.train -m ...) whose jobs started"
        )
    given = [
        dict(o.split("=", 1) for o in yaml.safe_load((j / ".hydra" / "overrides.yaml").read_text()) or [] if "=" in o)
        for j in jobs
    ]
    keys = [k for k in dict.fromkeys(k for g in given for k in g) if len({g.get(k) for g in given}) > 1]
    rows = []
    for job, values in zip(jobs, given):
        metrics = job / "test_metrics.json"
        tested = json.loads(metrics.read_text()) if metrics.is_file() else {}
        rows.append(
            {
                **{k: values.get(k, "") for k in keys},
                "job": str(job.relative_to(out)),
                **{f"test/{k}": v for k, v in tested.items()},
            }
        )
    return keys, rows


def sweep_markdown(keys: list[str], rows: list[dict]) -> str:
    """Every job as a row, then, for two varied keys, a keys[0] × keys[1] table per headline metric."""
    metrics = [m for m in dict.fromkeys(k for r in rows for k in r if k.startswith("test/"))]
    head = [*keys, *[m.removeprefix("test/") for m in metrics]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append(
            "| "
            + " | ".join([str(r[k]) for k in keys] + [f"{r[m]:.3g}" if m in r else "not finished" for m in metrics])
            + " |"
        )
    text = "\n".join(lines) + "\n"
    if len(keys) != 2:
        return text
    by = {(r[keys[0]], r[keys[1]]): r for r in rows}
    first, second = (
        sorted({r[k] for r in rows}, key=lambda v: (isinstance(_number(v), str), _number(v))) for k in keys
    )
    for metric in [m for m in ORDER if m in metrics and "baseline" not in m]:  # baselines: the same in every cell
        text += f"\n{metric.removeprefix('test/')}: {keys[0]} (rows) × {keys[1]} (columns)\n\n"
        text += (
            "| " + " | ".join([f"{keys[0]} \\ {keys[1]}", *second]) + " |\n" + "|" + "---|" * (len(second) + 1) + "\n"
        )
        for a in first:
            cells = [f"{by[a, b][metric]:.3g}" if metric in by.get((a, b), {}) else "—" for b in second]
            text += "| " + " | ".join([a, *cells]) + " |\n"
    return text


def write_sweep_report(out: str | Path) -> list[Path]:
    """``sweep.csv`` and ``sweep.md`` of the multirun folder ``out``; returns the files written."""
    out = Path(out)
    keys, rows = sweep_rows(out)
    write_csv(out / "sweep.csv", rows)
    text = sweep_markdown(keys, rows)
    write_text(out / "sweep.md", f"# {out.name}\n\n" + text)
    Console(width=200).print(text, markup=False)
    return [out / "sweep.csv", out / "sweep.md"]


def write_folder_report(folder: Path) -> list[Path]:
    """The report of ``folder``: a multirun's (it holds ``multirun.yaml``) or a benchmark's."""
    return (write_sweep_report if (folder / "multirun.yaml").is_file() else write_report)(folder)
