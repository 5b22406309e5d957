"""The summary a run or an ensemble prints at its end: a headline (which metric leads, and when the headline and
the whole window disagree) above one table of validation and test metrics, on the console and in the log files."""

from __future__ import annotations

import io
import math
from pathlib import Path

from rich.console import Console
from rich.table import Table

from encons.infra.progress import to_log_files


def print_summary(
    title: str, results: dict[str, float], output_dir: Path, note: str = "", console: bool = True
) -> None:
    """One table of the run's validation and test metrics, ``note`` (which weights were tested) and
    where its files are (those of checkpoints/, figures/ and test_metrics.json that it holds), on the console
    (unless ``console`` is false) and in the run's log files (``train.log`` under the CLI)."""
    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    windows = results.get("test/windows")
    for key in sorted(results):
        if key.startswith(("val/", "test/", "best/")) or key in ("wall_time_s", "threads", "best_epoch"):
            count = f" (mean of {windows:.0f} windows)" if key.endswith("/vpt") and windows is not None else ""
            table.add_row(key, f"{results[key]:.4g}{count}")
    out = Console(record=True) if console else Console(record=True, file=io.StringIO())
    for line in headline(results):
        out.print(line, markup=False)
    out.print(table)
    if note:
        out.print(note)
    held = []
    for name in ("checkpoints", "figures", "test_metrics.json"):
        path = output_dir / name
        if path.is_file():
            held.append(name)
        elif path.is_dir() and any(path.iterdir()):
            held.append(f"{name}/")
    out.print(f"outputs: {output_dir}" + (f"  ({', '.join(held)})" if held else ""))
    to_log_files(out.export_text())


FEW_WINDOWS = 5  # fewer test windows than this: a score with no spread worth the name


def headline(results: dict[str, float]) -> list[str]:
    """The lines above a run's table: the model and the baselines over the whole test window
    (``traj_rel_err_window``, ``state_mse``) with the number of test windows; a flag where the scored horizon
    (``traj_rel_err``, the papers' T = 4) orders them otherwise; a warning under ``FEW_WINDOWS`` windows."""
    windows = results.get("test/windows")
    if windows is None or "test/traj_rel_err_window" not in results:
        return []
    names = [
        "model",
        *(p.split("/")[1] for p in results if p.startswith("test/baseline_") and p.endswith("/traj_rel_err_window")),
    ]

    def score(name: str, metric: str) -> float:
        return results.get(f"test/{'' if name == 'model' else name + '/'}{metric}", math.nan)

    def listed(metric: str) -> str:
        return ", ".join(f"{name} {score(name, metric):.4g}" for name in names)

    def order(metric: str) -> list[str]:
        return sorted(names, key=lambda n: (math.isnan(score(n, metric)), score(n, metric)))

    lines = [
        f"whole test window, mean of {windows:.0f} test window(s): traj_rel_err_window "
        f"{listed('traj_rel_err_window')}"
        + (
            f"; state_mse (per coordinate / its test-set spread) {listed('state_mse')}"
            if "test/state_mse" in results
            else ""
        )
    ]
    whole, horizon = order("traj_rel_err_window"), order("traj_rel_err")
    if whole != horizon:
        lines.append(
            f"note: the scored horizon ranks them differently: traj_rel_err {' < '.join(horizon)}, but over "
            f"the whole window {' < '.join(whole)}"
        )
    if windows < FEW_WINDOWS:
        lines.append(
            f"note: {windows:.0f} test window(s) give these scores no spread to speak of (the _std are over "
            f"{windows:.0f}; more: data.n_test, or for a recording a longer file, "
            f"data.recording.test_stride, a shorter data.test_steps)"
        )
    return lines
