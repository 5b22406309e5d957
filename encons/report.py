"""Summary tables printed at the end of a run or a benchmark."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table


def print_summary(title: str, results: dict[str, float], output_dir: Path) -> None:
    """One table of the run's validation and test metrics, and where its files are."""
    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key in sorted(results):
        if key.startswith(("val/", "test/")) or key == "wall_time_s":
            table.add_row(key, f"{results[key]:.4g}")
    console = Console()
    console.print(table)
    console.print(f"outputs: {output_dir}  (checkpoints/, figures/, test_metrics.json)")
