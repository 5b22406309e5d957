"""Lightning callbacks: the run config in every checkpoint, a progress line per epoch (at most one every
``every_s`` seconds), a stall line, the best checkpoint and progress bar numbered like the log, and the one
writer of a test's results.

Epochs are numbered from 1 everywhere a user reads them (log lines, progress bar, ``best_epoch``, the best
checkpoint's file name): "epoch k" is the k-th pass over the training data; Lightning counts from 0
internally (``trainer.current_epoch``, a checkpoint's ``epoch`` entry)."""

from __future__ import annotations

import logging
import math
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import lightning.pytorch as pl
from lightning.pytorch.callbacks import ModelCheckpoint, RichProgressBar
from omegaconf import DictConfig, OmegaConf

from encons.evaluators import figures
from encons.infra import checkpoints
from encons.infra.bounds import Count, Positive
from encons.infra.compat import number_epochs_from_one
from encons.infra.io import save_npz, write_json
from encons.infra.progress import duration, to_log_files

if TYPE_CHECKING:
    from encons.training.members import EnsembleModule
    from encons.training.module import TrainingModule

log = logging.getLogger(__name__)


class RunConfigInCheckpoints(pl.Callback):
    """Stores the resolved run ``config`` in every checkpoint (``checkpoints.CONFIG_KEY``); on a resume
    into a new run folder, carries the earlier run's best checkpoint over so that the best is chosen
    among all epochs (Lightning keeps only its path when the folder changes)."""

    def __init__(self, config: DictConfig):
        self.config = OmegaConf.to_container(config)

    def on_save_checkpoint(self, trainer: pl.Trainer, pl_module: pl.LightningModule, checkpoint: dict) -> None:
        checkpoint[checkpoints.CONFIG_KEY] = self.config

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        callbacks = cast("list[ModelCheckpoint]", trainer.checkpoint_callbacks)  # encons' are ModelCheckpoints
        best = next((cb for cb in callbacks if cb.monitor), None)
        if trainer.ckpt_path is None or best is None:
            return
        state = checkpoints.read(trainer.ckpt_path, "ckpt_path")["callbacks"].get(best.state_key, {})
        old = Path(state.get("best_model_path") or "")
        if state.get("dirpath") == best.dirpath or not old.is_file() or state.get("best_model_score") is None:
            return
        new = Path(cast("str | Path", best.dirpath)) / old.name  # set: Lightning resolved it before training
        if trainer.is_global_zero:
            new.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(old, new)
        trainer.strategy.barrier()
        best.best_model_path = best.kth_best_model_path = str(new)
        best.best_model_score = best.kth_value = state["best_model_score"]
        best.best_k_models = {str(new): state["best_model_score"]}


class EpochLine(pl.Callback):
    """One line per training epoch — ``epoch k of N: train/loss …, val/… …, elapsed, ETA`` — in the run's
    log files (``train.log``), and on the console too when stdout is not a terminal (a job's output file,
    where the progress bar does not draw) and the run shows progress (``trainer.enable_progress_bar``):
    there the first and last epochs and at most one line every ``every_s`` seconds, so that a run of
    one-step epochs (a small file budgeted by ``trainer.max_steps``) does not print a line per step.
    The ETA assumes the remaining epochs (``trainer.max_epochs``) take as long as the past ones."""

    def __init__(self, metrics: tuple[str, ...] = ("train/loss", "val/loss"), every_s: Positive = 10.0):
        self.metrics, self.every_s = tuple(metrics), every_s

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.started, self.first_epoch = time.perf_counter(), trainer.current_epoch
        self.shown: float | None = None  # when the console last got a line

    def on_train_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        done = trainer.current_epoch + 1
        total = trainer.max_epochs if trainer.max_epochs and trainer.max_epochs > 0 else None
        now = time.perf_counter()
        elapsed = now - self.started
        keys = (*self.metrics, monitored(trainer))
        shown = [
            f"{k} {float(trainer.callback_metrics[k]):.4g}"
            for k in dict.fromkeys(keys)
            if k in trainer.callback_metrics
        ]
        eta = (
            f", ETA {duration(elapsed / (done - self.first_epoch) * (total - done))}"
            if total and done > self.first_epoch
            else ""
        )
        line = (
            f"epoch {done}{f' of {total}' if total else ''} (step {trainer.global_step}): {', '.join(shown)}, "
            f"elapsed {duration(elapsed)}{eta}"
        )
        last = done == total or (trainer.max_steps > 0 and trainer.global_step >= trainer.max_steps)
        due = self.shown is None or now - self.shown >= self.every_s or last
        if due and trainer.progress_bar_callback is not None and not sys.stdout.isatty():
            self.shown = now
            log.info(line)  # console and log files
        else:
            to_log_files(line)  # the log files only: the progress bar shows it live, or not yet due


class CostLine(pl.Callback):
    """What an epoch costs, split: ``validation`` (the validation loop), ``checkpoint`` (writing checkpoint
    files, ``encons.infra.lightning_io.AtomicCheckpointIO.seconds``) and ``train`` (the rest of the epoch: its
    optimiser steps, logging, callbacks), in seconds. One line per epoch in the log files, one line of
    means on the console at the end of fit, and ``costs.json`` in ``output_dir`` (per-epoch rows).

    Its state is in every checkpoint: a resumed run's ``costs.json`` has the epochs before the stop too (each
    epoch's row as it stood when its checkpoint was written), and ``before_s`` is the wall time of the run's
    earlier segments up to the checkpoint it resumed from, which the run's ``wall_time_s`` adds
    (``resumed_seconds``): what a run stopped and resumed took in all, less the work lost after its last
    checkpoint."""

    def __init__(self, output_dir: str | Path):
        self.output_dir = Path(output_dir)
        self.rows: list[dict[str, float]] = []
        self.open: dict[str, float] | None = None
        self.before_s = 0.0
        self.started = time.perf_counter()

    def on_fit_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.started = time.perf_counter()

    def state_dict(self) -> dict[str, Any]:
        now = time.perf_counter()
        current = [] if self.open is None else [self._row(self.open, now, 0.0)]  # its checkpoint is being written
        return {"rows": [*self.rows, *current], "wall_s": self.before_s + now - self.started}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.rows = list(state_dict["rows"])
        self.before_s = float(state_dict["wall_s"])

    def _written(self, trainer: pl.Trainer) -> float:
        return getattr(trainer.strategy.checkpoint_io, "seconds", 0.0)

    @staticmethod
    def _row(opened: dict[str, float], now: float, checkpoint: float) -> dict[str, float]:
        """An epoch's row from its open record at time ``now``, with ``checkpoint`` seconds of writing."""
        total = now - opened["start"]
        kept = {k: v for k, v in opened.items() if k not in ("start", "written")}
        return {**kept, "total": total, "checkpoint": checkpoint, "train": total - opened["validation"] - checkpoint}

    def _close(self, trainer: pl.Trainer) -> None:
        if self.open is None:
            return
        opened, self.open = self.open, None
        row = self._row(opened, time.perf_counter(), self._written(trainer) - opened["written"])
        self.rows.append(row)
        if trainer.is_global_zero:
            to_log_files(
                f"epoch {int(row['epoch'])} cost: train {row['train']:.3g} s, validation "
                f"{row['validation']:.3g} s, checkpoint {row['checkpoint']:.3g} s"
            )

    def on_train_epoch_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self._close(trainer)
        self.open = {
            "epoch": trainer.current_epoch + 1,
            "start": time.perf_counter(),
            "written": self._written(trainer),
            "validation": 0.0,
            "validated": 0,
        }

    def on_validation_epoch_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.val_start = time.perf_counter()

    def on_validation_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if self.open is not None and not trainer.sanity_checking:
            self.open["validation"] += time.perf_counter() - self.val_start
            self.open["validated"] = 1

    def on_train_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self._close(trainer)
        if not trainer.is_global_zero or not self.rows:
            return
        n = len(self.rows)
        mean = {k: sum(r[k] for r in self.rows) / n for k in ("train", "validation", "checkpoint", "total")}
        log.info(
            "cost per epoch (mean of %d): train %.3g s, validation %.3g s (%d validations), checkpoint %.3g s",
            n,
            mean["train"],
            mean["validation"],
            sum(int(r["validated"]) for r in self.rows),
            mean["checkpoint"],
        )
        self.output_dir.mkdir(parents=True, exist_ok=True)
        write_json(self.output_dir / "costs.json", {"mean": mean, "epochs": self.rows})


def resumed_seconds(trainer: pl.Trainer) -> float:
    """The wall time of the run's segments before the checkpoint ``trainer`` resumed from (``CostLine.before_s``);
    0 for a run that did not resume or has no ``CostLine``."""
    kept = trainer.callbacks  # type: ignore[attr-defined]  # set by Lightning's callback connector, untyped
    return next((c.before_s for c in kept if isinstance(c, CostLine)), 0.0)


def monitored(trainer: pl.Trainer) -> str:
    """The validation metric the best checkpoint follows (``optimized_metric``), else ``val/traj_rel_err``."""
    callbacks = cast("list[ModelCheckpoint]", trainer.checkpoint_callbacks)  # encons' are ModelCheckpoints
    return next((cb.monitor for cb in callbacks if cb.monitor), None) or "val/traj_rel_err"


class StallLine(pl.Callback):
    """Says once, as a warning, when the monitored validation metric (``monitored``) has stayed within
    ``rtol`` (relative) of one value for ``patience`` validations in a row: training has stalled — the
    model ends no better than where it froze, and the epochs left only cost time — with the likely remedies
    (the learning rate, another objective the model allows)."""

    def __init__(self, patience: Count = 20, rtol: Positive = 1e-6):
        self.patience, self.rtol = patience, rtol

    def on_fit_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.anchor: float | None = None
        self.since: int | None = None
        self.count, self.said = 0, False

    def on_validation_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        key = monitored(trainer)
        if trainer.sanity_checking or self.said or key not in trainer.callback_metrics:
            return
        value = float(trainer.callback_metrics[key])
        if self.anchor is not None and abs(value - self.anchor) <= self.rtol * abs(self.anchor):
            self.count += 1
        else:
            self.anchor, self.since, self.count = value, trainer.current_epoch + 1, 0
        if self.count < self.patience:
            return
        self.said = True
        others = [o for o in getattr(module.model, "objectives", ()) if o != getattr(module, "objective", None)]
        if trainer.is_global_zero:
            log.warning(
                "stalled: %s has stayed at %.6g (within %g relative) for %d validations since epoch %d (now epoch "
                "%d, step %d); the model is not learning. Likely remedies: another optimizer.lr (lower if the loss "
                "jumped before it froze, higher if it never moved)%s; callbacks.stall.patience=%d sets when this is "
                "said",
                key,
                value,
                self.rtol,
                self.count,
                self.since,
                trainer.current_epoch + 1,
                trainer.global_step,
                f", or objective={' / '.join(others)} (docs/data.md: which objective for a recording)"
                if others
                else "",
                self.patience,
            )


class BestCheckpoint(ModelCheckpoint):
    """Lightning's ``ModelCheckpoint`` whose file name counts epochs from 1, like the log lines
    (``best-epoch0094.ckpt`` holds the weights after the 94th epoch)."""

    def format_checkpoint_name(self, metrics: dict, *args, **kwargs) -> str:
        if "epoch" in metrics:
            metrics = {**metrics, "epoch": metrics["epoch"] + 1}
        return super().format_checkpoint_name(metrics, *args, **kwargs)


class ProgressBar(RichProgressBar):
    """Lightning's rich progress bar, numbering epochs from 1 (``Epoch 2/2`` in the second of two; no total
    when the run is budgeted by steps)."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        number_epochs_from_one(self)


class TestResults(pl.Callback):
    """The one writer of a test's results, after every evaluator (``encons.evaluators``) has scored:
    ``test_metrics.json`` and ``test_curves.npz`` (the module's merged ``test_metrics`` and ``test_curves``)
    and each evaluator's figures as ``figures/<stem>.png``, in ``output_dir``, each file atomically, once
    per test, by the global-zero process; figures also go to loggers that take images (wandb). ``figures``
    false (the run's ``figures=false``): metrics and curves only, no figure drawn."""

    def __init__(self, output_dir: str | Path, figures: bool = True):
        self.output_dir = Path(output_dir)
        self.figures = figures

    def on_test_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        module = cast("TrainingModule", module)  # the module a run tests
        drawing = module.evaluators.values() if self.figures else ()
        paths = [
            figures.save_png(fig, self.output_dir / "figures" / f"{stem}.png", layout=False)
            for evaluator in drawing
            for stem, fig in evaluator.figures(module).items()
        ]
        for logger in trainer.loggers:
            figures.log_figures(logger, paths)
        write_json(self.output_dir / "test_metrics.json", module.test_metrics)
        save_npz(self.output_dir / "test_curves.npz", **module.test_curves)


class MemberCheckpoints(pl.Callback):
    """Each member's best checkpoint by its own ``seed<k>/<monitor>``, as ``ModelCheckpoint`` (save_top_k 1)
    keeps a separate run's: written after each validation where the member improved (strictly; NaN never),
    the previous one removed. The file is a normal single-seed checkpoint: the member's ``state_dict``, its
    epoch and step, and its run config (``encons.infra.checkpoints.CONFIG_KEY``)."""

    def __init__(self, dirs: Sequence[Path], configs: Sequence[dict], monitor: str, mode: str = "min"):
        self.dirs, self.configs, self.monitor, self.mode = list(dirs), list(configs), monitor, mode
        self.best: dict[int, tuple[float, Path]] = {}

    def _better(self, value: float, best: float) -> bool:
        return not math.isnan(value) and (value < best if self.mode == "min" else value > best)

    def _save(self, trainer: pl.Trainer, module: EnsembleModule) -> None:
        from encons.infra.io import save_checkpoint

        for i in module.active:
            key = f"seed{module.seeds[i]}/{self.monitor}"
            if key not in trainer.callback_metrics:
                continue
            value = float(trainer.callback_metrics[key])
            old = self.best.get(i)
            if old is not None and not self._better(value, old[0]):
                continue
            if old is None and math.isnan(value):
                continue
            path = (
                self.dirs[i] / "checkpoints" / f"best-epoch{trainer.current_epoch + 1:04d}.ckpt"
            )  # from 1, as the log
            save_checkpoint(
                {
                    "epoch": trainer.current_epoch,
                    "global_step": trainer.global_step,
                    "pytorch-lightning_version": pl.__version__,
                    "state_dict": module.members[i].state_dict(),
                    checkpoints.CONFIG_KEY: self.configs[i],
                },
                path,
            )
            if old is not None and old[1] != path:
                old[1].unlink(missing_ok=True)
            self.best[i] = (value, path)

    def state_dict(self) -> dict:  # in the ensemble's last.ckpt: a resumed ensemble keeps its members' bests
        return {"best": {i: [value, str(path)] for i, (value, path) in self.best.items()}}

    def load_state_dict(self, state_dict: dict) -> None:
        self.best = {int(i): (float(value), Path(path)) for i, (value, path) in state_dict["best"].items()}

    def on_validation_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not trainer.sanity_checking:
            self._save(trainer, cast("EnsembleModule", module))  # an ensemble's callback

    def on_train_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not self.monitor.startswith("val/"):
            self._save(trainer, cast("EnsembleModule", module))  # an ensemble's callback
