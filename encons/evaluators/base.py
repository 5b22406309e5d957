"""The evaluator interface: what a test run scores, one class per way of scoring.

The LightningModule (``encons.training.module.TrainingModule``) holds the run's evaluators (``conf/evaluators``,
chosen as ``evaluators=[states,santos]``). At the start of testing it calls each one's ``reset``; on
every test batch ``update`` with that batch's :class:`TestBatch`; at the end of the test epoch
``compute``, whose :class:`Result` it merges (a metric or curve name given twice is an error) and logs as
``test/<name>``; where figures are saved, ``figures``. One writer (``encons.training.callbacks.TestResults``)
saves the merged metrics (``test_metrics.json``), curves (``test_curves.npz``) and figures
(``figures/<stem>.png``) once. Hooks run inside Lightning's test loop: no gradients, the model in eval mode.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import torch
from matplotlib.figure import Figure
from torch import Tensor

if TYPE_CHECKING:
    from encons.numerics.learner import Learner


@dataclass
class Result:
    """What one evaluator scored: scalar ``metrics`` and per-step ``curves`` (arrays), by name."""

    metrics: dict[str, float] = field(default_factory=dict)
    curves: dict[str, np.ndarray] = field(default_factory=dict)


class TestBatch:
    """One test batch as every evaluator sees it: the ``batch`` dict, its observations ``x`` and the
    states they encode to, and ``pred``, the model's rollout from the first state(s) by the run's
    ``evaluation`` — computed once, on first use, and shared by the evaluators that read it."""

    __test__ = False  # not a pytest class

    def __init__(self, module: Learner, batch: dict[str, Tensor]):
        self.module, self.batch = module, batch
        self.x, self.states = module.observe(batch)

    @cached_property
    def pred(self) -> Tensor:
        return self.module.predict(self.batch, self.states, self.module.evaluation)


class Evaluator(ABC):
    """One way to score a trained model at test time: one class and one ``conf/evaluators/<name>.yaml``
    (``# @package evaluators.<name>``, ``_target_`` and the constructor's arguments).

    ``headline`` declares which of its metrics (as ``compute`` names them) a benchmark summary's headline
    table shows: a benchmark run records them in its result row, and the report gathers them from there
    (``encons.tools.report.headline``)."""

    headline: ClassVar[tuple[str, ...]] = ()

    def check(self, module: Learner) -> None:
        """Refuse, with one ``ConfigError`` line, a run this evaluator cannot score (called when the
        module is built). Default: every run."""

    def reset(self) -> None:
        """Forget what earlier tests fed in. Default: nothing kept."""

    def update(self, module: Learner, batch: TestBatch) -> None:
        """Take one test batch. Default: ignore it (an evaluator that draws its own data)."""

    @abstractmethod
    def compute(self, module: Learner) -> Result:
        """The scores over every test batch fed in since ``reset`` (under DDP, every process's share)."""

    def figures(self, module: Learner) -> dict[str, Figure]:
        """Figures of the last ``compute``, laid out, by file stem; called only where they are saved
        (a run with an output folder, its global-zero process). Default: none."""
        return {}

    def ensemble_figures(self, module: Learner, members: list[Evaluator], seeds: list[int]) -> dict[str, Figure]:
        """Figures of a seed ensemble (``encons.training.ensemble``), from its ``members``' evaluators of this name
        after each member's test (``module``: the first member): where the members' spread shows. Default: none."""
        return {}


def gathered(module: Learner, batches: list[tuple[Tensor, ...]]) -> list[Tensor]:
    """The kept per-batch tensors concatenated along the batch; under DDP, every process's share
    (``LightningModule.all_gather``)."""
    parts = [torch.cat(p) for p in zip(*batches)]
    if module.trainer.world_size > 1:
        parts = [module.all_gather(p).flatten(0, 1) for p in parts]
    return parts
