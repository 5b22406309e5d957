"""Summary tables printed at the end of a run or a benchmark, and copied into the run's log file."""

from __future__ import annotations

import logging
import sys
import time
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


class Progress:
    """``<what> k of n (label), elapsed, ETA`` lines for a loop over items of known relative cost.

    Lines go to ``log`` at INFO if given (the run's console and log file), else to stderr.
    """

    def __init__(self, items: int, what: str, log: logging.Logger | None = None, work: float | None = None):
        self.items, self.what, self.log = items, what, log
        self.total = float(items if work is None else work)  # the ETA assumes work proceeds at one rate
        self.done_work, self.count, self.started = 0.0, 0, time.perf_counter()

    def start(self, label: str, work: float = 1.0) -> None:
        """Item ``label`` begins; ``work`` is its cost in the units of ``work`` (one item by default)."""
        elapsed = time.perf_counter() - self.started
        eta = (f", ETA {_duration(elapsed / self.done_work * (self.total - self.done_work))}"
               if self.done_work else "")
        self.count += 1
        self.done_work += work
        self._say(f"{self.what} {self.count} of {self.items} ({label}), elapsed {_duration(elapsed)}{eta}")

    def done(self) -> None:
        self._say(f"{self.what} {self.count} of {self.items} done in {_duration(time.perf_counter() - self.started)}")

    def _say(self, line: str) -> None:
        if self.log is not None:
            self.log.info(line)
        else:
            print(line, file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes // 60}h{minutes % 60:02d}m" if minutes >= 60 else f"{minutes}m{secs:02d}s"
