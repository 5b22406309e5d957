"""Every use of an upstream library's private internals or message text, in one place.

Each function names the upstream version it was written against (the pins in pyproject.toml);
``tests/infra/test_compat.py`` holds one test per workaround, so an upgrade that breaks one fails there.
"""

from __future__ import annotations

import functools
import logging
import re
import warnings
from pathlib import Path
from typing import Any, Callable


def ode_methods() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """torchdiffeq 0.2.5's method names and those with a fixed step (``_impl``: no public list)."""
    from torchdiffeq._impl.odeint import SOLVERS
    from torchdiffeq._impl.solvers import FixedGridODESolver

    fixed = (m for m, solver in SOLVERS.items() if issubclass(solver, FixedGridODESolver))
    return tuple(sorted(SOLVERS)), tuple(sorted(fixed))


def optuna_search_space(overrides: list[str]) -> tuple[dict, dict, list[str]]:
    """hydra-optuna-sweeper 1.4.0rc3's parse of sweep overrides into (distributions, fixed values,
    fixed overrides) (``_impl.create_params_from_overrides``: not exported)."""
    from hydra_plugins.hydra_optuna_sweeper._impl import create_params_from_overrides

    return create_params_from_overrides(overrides)


def job_exception(ret: Any) -> BaseException:
    """The exception of a failed Hydra 1.4 ``JobReturn`` (``return_value`` re-raises it)."""
    return ret._return_value


def drop_wandb_anonymous(logger: Any) -> None:
    """Lightning 2.6's ``WandbLogger`` passes ``anonymous=None``, which wandb 0.31 warns about on
    every run; remove it from the logger's pending ``wandb.init`` keywords (``_wandb_init``)."""
    if getattr(logger, "_wandb_init", {}).get("anonymous", False) is None:
        del logger._wandb_init["anonymous"]


_MISSING_MONITOR = re.compile(r"could not find the monitored key in the returned metrics: \[([^]]*)\]")


def logged_metric_names(err: Exception) -> list[str] | None:
    """The metric names a Lightning 2.6 ``MisconfigurationException`` lists when a checkpoint's
    ``monitor`` was never logged (only its message says so), or None for any other error."""
    found = _MISSING_MONITOR.search(str(err))
    return None if found is None else [n.strip(" '") for n in found.group(1).split(",") if "/" in n]


class _DropTips(logging.Filter):
    """Drops Lightning's advertising tips ("💡 Tip: ... try installing litlogger")."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("💡")


class _DeviceLinesOffConsole(logging.Filter):
    """Drops Lightning 2.6's "GPU available: ... / TPU available: ..." lines (the device is in the run's
    config and train.log); set on console handlers only, so the log files keep them."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (
            record.name.startswith("lightning") and str(record.msg).startswith(("GPU available", "TPU available"))
        )


#: torch 2.13's DDP reducer warning (c10d/reducer.cpp) for a gradient of shape (1, n) or (n, 1)
GRAD_STRIDES_OF_A_ROW_OR_COLUMN = (
    r"(?s)Grad strides do not match bucket view strides.*grad\.sizes\(\) = \[(1, \d+|\d+, 1)\], strides"
)


def quiet_upstream() -> None:
    """Silence upstream messages a user cannot act on: Lightning 2.6's tips and its deprecation
    warning about torch 2.13's pytree ``LeafSpec``, the notice of a resume into a new folder, and its advice
    to add DataLoader workers on machines of more than 2 cores (encons' windows are slices of tensors in
    memory: workers would only copy them between processes; no key sets them); its device lines on the
    console (Hydra's, or one a script set up), kept in the log files. And torch 2.13 DDP's "Grad strides do not
    match bucket view strides" where the tensor is a row or a column ((1, n) or (n, 1): the last layer of a network
    with one output, e.g. SyMo's M(q) of one coordinate): mm's backward gives such a weight's gradient strides
    that differ from the parameter's only on the size-1 axis, the same memory order, so nothing is slower; a
    mismatch on any other shape still warns."""
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)")
    warnings.filterwarnings("ignore", message=GRAD_STRIDES_OF_A_ROW_OR_COLUMN)
    warnings.filterwarnings("ignore", message="The dirpath has changed from")
    warnings.filterwarnings("ignore", message=r"The '\w+' does not have many workers")
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
        logging.getLogger(name).addFilter(_DropTips())  # the loggers rank_zero_info writes to
    for handler in logging.getLogger().handlers:
        if type(handler) is logging.StreamHandler and not any(
            isinstance(f, _DeviceLinesOffConsole) for f in handler.filters
        ):
            handler.addFilter(_DeviceLinesOffConsole())


def bare_optimizer(optimizer: Any) -> None:
    """torch 2.13's hook dicts that ``torch.optim.Optimizer.__init__`` sets (private), for an optimiser that
    does not call it because its parameter groups are other optimisers' (``encons.training.members``)."""
    for name in ("step", "state_dict", "load_state_dict"):
        setattr(optimizer, f"_optimizer_{name}_pre_hooks", {})
        setattr(optimizer, f"_optimizer_{name}_post_hooks", {})


def number_epochs_from_one(bar: Any) -> None:
    """Lightning 2.6's ``RichProgressBar`` ``bar`` numbering epochs from 1, like the log lines (``Epoch 2/2`` in the
    second of two; no total when the run is budgeted by steps), through its private hook ``_get_train_description``."""
    bar._get_train_description = functools.partial(_train_description_from_one, bar)


def _train_description_from_one(bar: Any, current_epoch: int) -> str:
    total = bar.trainer.max_epochs
    text = f"Epoch {current_epoch + 1}" + (f"/{total}" if total is not None and total > 0 else "")
    return f"{text:{len(bar.validation_description)}}" if len(bar.validation_description) > len(text) else text


def csv_experiment(logger: Any, writer: Callable[..., Any]) -> Any:
    """Lightning 2.6's ``CSVLogger.experiment`` with its writer made by ``writer(log_dir=...)``: the logger's writer
    (private ``_experiment``), made on first use, after its folder is created through its filesystem (``_fs``)."""
    if logger._experiment is None:
        logger._fs.makedirs(logger.root_dir, exist_ok=True)
        logger._experiment = writer(log_dir=logger.log_dir)
    return logger._experiment


def record_new_metric_keys(writer: Any) -> None:
    """Lightning 2.6's CSV ``ExperimentWriter`` adds the keys of its pending ``metrics`` to ``metrics_keys``
    (private ``_record_new_keys``), as its own ``save`` does before writing."""
    writer._record_new_keys()


def retarget_file_logs(old: Path, new: Path) -> list[logging.FileHandler]:
    """The root logger's file handlers writing to ``old`` (Hydra's job log, ``train.log``) made to append to ``new``
    instead (Python 3.11's ``FileHandler``: ``baseFilename``, and the stream that ``emit`` reopens after ``close``).
    Returns the handlers moved."""
    import os

    moved = []
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler) and handler.baseFilename == os.path.abspath(old):
            handler.acquire()
            try:
                handler.close()  # flushed and closed; emit() reopens baseFilename (mode "a" once opened)
                handler.baseFilename = os.path.abspath(new)
                handler.mode = "a"
            finally:
                handler.release()
            moved.append(handler)
    return moved
