"""Hydra entry point: ``python -m encons.train model=<model> system=<system> [overrides]``.

Builds system → data → model → LightningModule from the composed config (``encons.api.train``),
trains, tests the best-by-validation checkpoint, prints a summary table and returns that
checkpoint's ``optimized_metric`` value (for sweeps).
"""

from __future__ import annotations

import os
from contextlib import nullcontext

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from encons import api, help
from encons.errors import one_line_errors
from encons.paths import config_dir


@hydra.main(config_path=config_dir(), config_name="train", execution_whitelist=api.trusted_targets())
def _hydra_main(cfg: DictConfig) -> float | None:
    # a single run reports a user's error here, before Hydra adds its own "Error executing job" line;
    # in a sweep the error goes to the sweeper, which records the trial as failed and goes on
    single = HydraConfig.get().mode == RunMode.RUN
    with one_line_errors() if single else nullcontext():
        results = api.train(cfg).metrics
    return results.get(f"best/{cfg.optimized_metric}", results.get(cfg.optimized_metric))


def main() -> None:
    os.environ.setdefault("WANDB_SILENT", "true")
    api.quiet_upstream()
    help.register()
    # Hydra then lets its own errors through to us (else it prints them with its search path and
    # exits 1): a user's error becomes the last line printed, a bug keeps its traceback.
    os.environ["HYDRA_FULL_ERROR"] = "1"
    with one_line_errors():
        _hydra_main()


api._callable_module(__name__, api.train)  # ``encons.train(cfg)`` stays the API function

if __name__ == "__main__":
    main()
