"""Hydra entry point: ``python -m encons.train model=<model> system=<system> [overrides]``.

Builds system → data → model → LightningModule from the composed config (``encons.api.train``),
trains, tests the best-by-validation checkpoint, prints a summary table and returns that
checkpoint's ``optimized_metric`` value (for sweeps).
"""

from __future__ import annotations

import os
import re
import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import (ConfigCompositionException, InstantiationException, MissingConfigException,
                          OverrideParseException)
from hydra.types import RunMode
from omegaconf import DictConfig

from encons import api
from encons.errors import EnconsError
from encons.paths import config_dir


@hydra.main(config_path=config_dir(), config_name="train", execution_whitelist=api.trusted_targets())
def _hydra_main(cfg: DictConfig) -> float | None:
    try:
        results = api.train(cfg).metrics
    except (EnconsError, InstantiationException) as err:
        if HydraConfig.get().mode == RunMode.MULTIRUN:
            raise  # the sweeper records the trial as failed and goes on
        print(f"encons: error: {_one_line(err)}", file=sys.stderr)
        sys.exit(2)
    return results.get(f"best/{cfg.optimized_metric}", results.get(cfg.optimized_metric))


def _one_line(err: Exception) -> str:
    if isinstance(err, InstantiationException):
        return f"{str(err).splitlines()[0]} ({err.__cause__})"
    return str(err)


def main() -> None:
    os.environ.setdefault("WANDB_SILENT", "true")
    api.quiet_upstream()
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
        return f"{group}={name} is unknown; allowed: {', '.join(sorted(o for o in err.options if not o.startswith('_')))}"
    lines = str(err).strip().splitlines()
    missing = re.match(r"Could not override '([^']+)'", lines[0])
    if missing:
        return (f"{missing.group(1)} is not a key of the config; allowed: the keys `--cfg job` prints, "
                f"or +{missing.group(1)}=VALUE to add one")
    return lines[0] + ("; allowed: key=value overrides (Hydra's override grammar)"
                       if isinstance(err, OverrideParseException) else "")


api._callable_module(__name__, api.train)  # ``encons.train(cfg)`` stays the API function

if __name__ == "__main__":
    main()
