"""Lightning callbacks: the run config in every checkpoint, a per-epoch progress line, and the one writer of
a test's results."""

from __future__ import annotations

import logging
import shutil
import sys
import time
from pathlib import Path

import lightning.pytorch as pl
from omegaconf import DictConfig, OmegaConf

from encons import checkpoints, plots
from encons.io import save_npz, write_json
from encons.progress import duration, to_log_files

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
        best = next((cb for cb in trainer.checkpoint_callbacks if cb.monitor), None)
        if trainer.ckpt_path is None or best is None:
            return
        state = checkpoints.read(trainer.ckpt_path, "ckpt_path")["callbacks"].get(best.state_key, {})
        old = Path(state.get("best_model_path") or "")
        if state.get("dirpath") == best.dirpath or not old.is_file() or state.get("best_model_score") is None:
            return
        new = Path(best.dirpath) / old.name
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
    where the progress bar does not draw) and the run shows progress (``trainer.enable_progress_bar``).
    The ETA assumes the remaining epochs (``trainer.max_epochs``) take as long as the past ones."""

    def __init__(self, metrics: tuple[str, ...] = ("train/loss", "val/loss")):
        self.metrics = tuple(metrics)

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.started, self.first_epoch = time.perf_counter(), trainer.current_epoch

    def on_train_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        done = trainer.current_epoch + 1
        total = trainer.max_epochs if trainer.max_epochs and trainer.max_epochs > 0 else None
        elapsed = time.perf_counter() - self.started
        monitor = trainer.checkpoint_callback.monitor if trainer.checkpoint_callback is not None else None
        keys = (*self.metrics, monitor or "val/traj_rel_err")
        shown = [f"{k} {float(trainer.callback_metrics[k]):.4g}" for k in dict.fromkeys(keys)
                 if k in trainer.callback_metrics]
        eta = (f", ETA {duration(elapsed / (done - self.first_epoch) * (total - done))}"
               if total and done > self.first_epoch else "")
        line = (f"epoch {done}{f' of {total}' if total else ''} (step {trainer.global_step}): {', '.join(shown)}, "
                f"elapsed {duration(elapsed)}{eta}")
        if trainer.progress_bar_callback is not None and not sys.stdout.isatty():
            log.info(line)              # console and log files
        else:
            to_log_files(line)          # the log files only: the progress bar shows it live


class TestResults(pl.Callback):
    """The one writer of a test's results, after every evaluator (``encons.evaluators``) has scored:
    ``test_metrics.json`` and ``test_curves.npz`` (the module's merged ``test_metrics`` and ``test_curves``)
    and each evaluator's figures as ``figures/<stem>.png``, in ``output_dir``, each file atomically, once
    per test, by the global-zero process; figures also go to loggers that take images (wandb)."""

    def __init__(self, output_dir: str | Path):
        self.output_dir = Path(output_dir)

    def on_test_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        paths = [plots.save_png(fig, self.output_dir / "figures" / f"{stem}.png", layout=False)
                 for evaluator in module.evaluators.values() for stem, fig in evaluator.figures(module).items()]
        for logger in trainer.loggers:
            plots.log_figures(logger, paths)
        write_json(self.output_dir / "test_metrics.json", module.test_metrics)
        save_npz(self.output_dir / "test_curves.npz", **module.test_curves)
