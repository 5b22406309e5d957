"""Hydra entry point: ``python -m encons.train model=<model> system=<system> [overrides]``.

Builds system → data → model → LightningModule from the composed config, trains, tests,
prints a summary table and returns the metric named by ``optimized_metric`` (for sweeps).
"""

from __future__ import annotations

import logging
import os
import re
import sys
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
import lightning.pytorch as pl
from hydra.errors import (ConfigCompositionException, InstantiationException, MissingConfigException,
                          OverrideParseException)
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from encons.config import build_model, build_system, check_config, instantiate_node, objective_of, resolve_checkpoint
from encons.data.datamodule import TrajectoryDataModule
from encons.errors import ConfigError, EnconsError
from encons.module import DynamicsModule
from encons.paths import config_dir
from encons.report import print_summary

log = logging.getLogger("encons")


def build(cfg: DictConfig) -> tuple[TrajectoryDataModule, DynamicsModule]:
    """System → data → model → LightningModule from a composed config, seeded by ``cfg.seed``."""
    check_config(cfg)
    pl.seed_everything(cfg.seed, workers=True, verbose=False)
    system = build_system(cfg)
    model = build_model(cfg, system)
    objective = objective_of(cfg)
    data_cfg = {**OmegaConf.to_container(cfg.data, resolve=True), "objective": objective}
    data = TrajectoryDataModule(system, model.chart, OmegaConf.to_container(cfg.system, resolve=True),
                                cache_dir=cfg.paths.cache_dir, **data_cfg)
    data.prepare_data()
    data.setup()
    test_steps = data.states["test"].shape[1] - 1
    if cfg.horizon > test_steps:
        raise ConfigError(f"horizon={cfg.horizon} exceeds the {test_steps} steps of a test trajectory; "
                          f"allowed: 1..{test_steps}")
    regulariser = instantiate_node(cfg, "regulariser") if cfg.get("regulariser") else None
    module = DynamicsModule(model, system, data.dt, instantiate_node(cfg, "integrator"), objective=objective,
                            regulariser=regulariser, horizon=cfg.horizon, output_dir=cfg.paths.output_dir,
                            **cfg.optim)
    return data, module


def run_config(cfg: DictConfig) -> DictConfig:
    """The resolved run config without Hydra's own node: what ``encons.evaluate`` rebuilds from."""
    node = lambda key: OmegaConf.to_container(cfg[key], resolve=True) if OmegaConf.is_config(cfg[key]) else cfg[key]
    return OmegaConf.create({key: node(key) for key in cfg if key != "hydra"})


def build_trainer(cfg: DictConfig) -> tuple[pl.Trainer, list]:
    """The Lightning Trainer of ``cfg.trainer`` with the configured loggers and callbacks."""
    loggers = [instantiate(c) for c in (cfg.get("logger") or {}).values()]
    callbacks = [instantiate(c) for c in (cfg.get("callbacks") or {}).values()]
    trainer = instantiate(cfg.trainer, logger=loggers or False, callbacks=callbacks)
    return trainer, loggers


def train(cfg: DictConfig) -> dict[str, float]:
    """Train and test one model on one system; return every logged metric as floats."""
    started = time.perf_counter()
    data, module = build(cfg)
    output_dir = Path(cfg.paths.output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(run_config(cfg), output_dir / "config.yaml")
    trainer, loggers = build_trainer(cfg)
    for lg in loggers:
        lg.log_hyperparams(OmegaConf.to_container(cfg, resolve=True))
    try:
        trainer.fit(module, datamodule=data, ckpt_path=resolve_checkpoint(cfg))
        results = {k: float(v) for k, v in trainer.callback_metrics.items()}
        if cfg.test:
            trainer.test(module, datamodule=data, verbose=False)
            results.update({f"test/{k}": v for k, v in module.test_metrics.items()})
    finally:
        _finish_wandb(loggers)
    results["wall_time_s"] = time.perf_counter() - started
    if trainer.is_global_zero:
        print_summary(module.run_title(), results, output_dir)
    return results


def _finish_wandb(loggers: list) -> None:
    if any(type(lg).__name__ == "WandbLogger" for lg in loggers):
        import wandb

        wandb.finish()


@hydra.main(config_path=config_dir(), config_name="train")
def _hydra_main(cfg: DictConfig) -> float | None:
    try:
        results = train(cfg)
    except (EnconsError, InstantiationException) as err:
        if HydraConfig.get().mode == RunMode.MULTIRUN:
            raise  # the sweeper records the trial as failed and goes on
        print(f"encons: error: {_one_line(err)}", file=sys.stderr)
        sys.exit(2)
    return results.get(cfg.optimized_metric)


def _one_line(err: Exception) -> str:
    if isinstance(err, InstantiationException):
        return f"{str(err).splitlines()[0]} ({err.__cause__})"
    return str(err)


def main() -> None:
    os.environ.setdefault("WANDB_SILENT", "true")
    # Hydra then lets its own errors through to us (else it prints them with its search path and
    # exits 1): a user's error becomes the last line printed, a bug keeps its traceback.
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        _hydra_main()
    except (EnconsError, ConfigCompositionException, OverrideParseException) as err:
        print(f"encons: error: {_composition_line(err)}", file=sys.stderr)
        sys.exit(2)
    except (FileExistsError, NotADirectoryError, PermissionError) as err:  # e.g. Hydra creating hydra.run.dir
        print(f"encons: error: {err.filename!r}: {err.strerror}; allowed: a writable folder for hydra.run.dir, "
              f"hydra.sweep.dir and paths.*", file=sys.stderr)
        sys.exit(2)


def _composition_line(err: Exception) -> str:
    if isinstance(err, MissingConfigException) and err.missing_cfg_file and err.options:
        group, _, name = err.missing_cfg_file.rpartition("/")
        return f"{group}={name} is unknown; allowed: {', '.join(sorted(err.options))}"
    lines = str(err).strip().splitlines()
    missing = re.match(r"Could not override '([^']+)'", lines[0])
    if missing:
        return (f"{missing.group(1)} is not a key of the config; allowed: the keys `--cfg job` prints, "
                f"or +{missing.group(1)}=VALUE to add one")
    return lines[0] + ("; allowed: key=value overrides (Hydra's override grammar)"
                       if isinstance(err, OverrideParseException) else "")


if __name__ == "__main__":
    main()
