"""The Python API: compose a config, build, train, load a run back, evaluate it, roll a model out.

    import encons
    cfg = encons.compose("model=hnn_angle", "system=pendulum1", "debug=fast")
    run = encons.train(cfg)              # Run: trained module (best checkpoint), metrics, run folder
    again = encons.load(run.run_dir)     # from the checkpoint alone: it carries its config
    encons.evaluate(again)               # the same test metrics, to the digit

A facade over ``encons.training.build`` (compose, instantiate), ``encons.config.check`` (validate once) and
``encons.training.runs`` (train, load, evaluate); the CLI (``encons.entry.cli``) calls the same functions. Lightning and
torch are imported on first use, not at import.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig

from encons.config.check import Checked, Request, validate
from encons.training import build as _builders
from encons.training import runs
from encons.training.build import catalogue
from encons.training.build import compose as _compose
from encons.training.results import Ensemble, Run
from encons.training.runs import evaluate, load

if TYPE_CHECKING:
    from encons.data.datamodule import TrajectoryDataModule
    from encons.training.module import TrainingModule

__all__ = [
    "Run",
    "Ensemble",
    "compose",
    "validate",
    "build",
    "build_trainer",
    "train",
    "load",
    "evaluate",
    "rollout",  # noqa: F822 - served by the module __getattr__ below (imported on first use)
    "catalogue",
]


def __getattr__(name: str):  # ``rollout`` re-exported without importing torch at ``import encons.entry.api``
    if name == "rollout":
        from encons.numerics.integrators import rollout

        return rollout
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build(
    cfg: DictConfig | Checked, request: Request | None = None, recorded: Mapping[str, float] | None = None
) -> tuple[TrajectoryDataModule, TrainingModule]:
    """The data module and LightningModule of a config (``encons.training.build.build``), without training: a
    ``Checked`` one as it is, a plain one validated first (``validate``, with ``request``: default the one its
    ``hydra`` node carries)."""
    return _builders.build(cfg if isinstance(cfg, Checked) else validate(cfg, request), recorded)


def build_trainer(cfg: DictConfig | Checked, request: Request | None = None) -> tuple[Any, list]:
    """The Lightning Trainer and loggers of a config (``encons.training.build.build_trainer``): a ``Checked``
    one as it is, a plain one validated first."""
    return _builders.build_trainer(cfg if isinstance(cfg, Checked) else validate(cfg, request))


def train(cfg: DictConfig | str | Sequence[str], summary: bool = True) -> Run | Ensemble:
    """Train a composed config, or the config ``compose`` makes of overrides (a string or a list of them).
    See :func:`encons.training.runs.train`."""
    return runs.train(cfg if isinstance(cfg, DictConfig) else compose(cfg), summary)


def compose(
    *overrides: str | Sequence[str], output_dir: str | Path | None = None, cache_dir: str | Path | None = None
) -> DictConfig:
    """The run config the CLI would compose from ``overrides`` (``"model=hnn"``, ``"trainer.max_epochs=5"``;
    a list works too). ``output_dir`` defaults to the CLI's run folder (``outputs/<system>-<model>/<time>``)."""
    flat = [o for item in overrides for o in ([item] if isinstance(item, str) else item)]
    return _compose(flat, output_dir, cache_dir)
