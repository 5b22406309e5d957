"""Lightning's file writers made atomic: checkpoints (its ``CheckpointIO`` plugin seam) and the CSV logger."""

from __future__ import annotations

import csv
import os
import time
from pathlib import Path
from typing import Any

from lightning.fabric.plugins.io.torch_io import TorchCheckpointIO
from lightning.pytorch.loggers import CSVLogger as _CSVLogger
from lightning.pytorch.loggers.csv_logs import ExperimentWriter
from lightning.pytorch.loggers.logger import rank_zero_experiment

from encons.infra.compat import csv_experiment, record_new_metric_keys
from encons.infra.io import atomic_open, save_checkpoint, write_yaml


class AtomicCheckpointIO(TorchCheckpointIO):
    """Writes each checkpoint through :func:`encons.infra.io.save_checkpoint`: a temporary file in the
    checkpoint's own folder, fsync, rename. Lightning's own writer stages the file in the system's
    temporary folder and moves it (a copy across disks, which a full disk cuts short under the final
    name); here a full or read-only disk is one ``WriteError`` and the earlier checkpoint stays.
    Reading and removing are Lightning's. ``seconds``: the time spent writing so far
    (``encons.training.callbacks.CostLine`` reads it)."""

    seconds = 0.0

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: str | Path, storage_options: Any | None = None
    ) -> None:  # path: Lightning's _PATH, str | Path
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__}.save_checkpoint takes no storage_options")
        start = time.perf_counter()
        save_checkpoint(checkpoint, path)
        self.seconds += time.perf_counter() - start


class CSVLogger(_CSVLogger):
    """Lightning's ``CSVLogger`` whose ``metrics.csv`` and ``hparams.yaml`` are rewritten whole and atomically
    at each save (``encons.infra.io``), so a full disk keeps the last complete table. Hyperparameters must be
    plain YAML values (encons logs its resolved run config)."""

    @property
    @rank_zero_experiment
    def experiment(self) -> ExperimentWriter:
        return csv_experiment(self, _AtomicExperimentWriter)


class _AtomicExperimentWriter(ExperimentWriter):
    def log_hparams(self, params: dict[str, Any]) -> None:
        self.hparams.update(params)
        write_yaml(os.path.join(self.log_dir, self.NAME_HPARAMS_FILE), self.hparams)

    def save(self) -> None:
        if not self.metrics:
            return
        record_new_metric_keys(self)
        rows: list[dict[str, Any]] = []
        if os.path.isfile(self.metrics_file_path):
            with open(self.metrics_file_path, newline="") as f:
                rows = list(csv.DictReader(f))
        with atomic_open(self.metrics_file_path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=self.metrics_keys)
            writer.writeheader()
            writer.writerows(rows + self.metrics)
        self.metrics = []
