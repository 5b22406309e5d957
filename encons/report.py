"""Summary tables printed at the end of a run or a benchmark, and copied into the run's log file."""

from __future__ import annotations

import logging
from pathlib import Path

from rich.console import Console
from rich.table import Table


def print_summary(title: str, results: dict[str, float], output_dir: Path, note: str = "") -> None:
    """One table of the run's validation and test metrics, ``note`` (which weights were tested) and
    where its files are; the same text goes to the run's log files (``train.log`` under the CLI)."""
    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key in sorted(results):
        if key.startswith(("val/", "test/", "best/")) or key in ("wall_time_s", "best_epoch"):
            table.add_row(key, f"{results[key]:.4g}")
    console = Console(record=True)
    console.print(table)
    if note:
        console.print(note)
    console.print(f"outputs: {output_dir}  (checkpoints/, figures/, test_metrics.json)")
    to_log_files(console.export_text())


def to_log_files(text: str, level: int = logging.INFO) -> None:
    """Write ``text`` to the file handlers of the root logger only (Hydra's ``<job>.log``), not the console."""
    record = logging.LogRecord("encons", level, __file__, 0, "%s", (text.rstrip(),), None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler) and record.levelno >= handler.level:
            handler.handle(record)
