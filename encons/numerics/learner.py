"""What objectives (``encons.training.objectives``) and evaluators (``encons.evaluators``) see of the run's
LightningModule: the narrow :class:`Learner` interface, on a floor below them both.

``encons.training.module.TrainingModule`` is the one implementation; an objective or evaluator types its
``module`` argument as ``Learner`` and so depends on this file, never on ``encons.training.module``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import torch
    from torch import Tensor

    from encons.models.base import DynamicsModel
    from encons.models.observation import Observation
    from encons.numerics.evaluation import Evaluation
    from encons.numerics.integrators import Integrator
    from encons.systems.base import System


class Learner(Protocol):
    """A model being trained or tested on a system's windows sampled every ``dt`` (the attributes and
    methods of ``encons.training.module.TrainingModule`` that objectives and evaluators read)."""

    model: DynamicsModel
    system: System
    observation: Observation
    integrator: Integrator
    evaluation: Evaluation
    dt: float
    horizon: int
    test_metrics: dict[str, float]
    test_curves: dict[str, Any]

    @property
    def evaluators(self) -> Mapping[str, Any]: ...

    @property
    def device(self) -> torch.device: ...

    @property
    def compared_angles(self) -> Tensor | None: ...

    @property
    def trainer(self) -> Any: ...

    def times(self, length: int, like: Tensor) -> Tensor: ...

    def observe(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]: ...

    def predict(
        self, batch: dict[str, Tensor], states: Tensor | None = None, evaluation: Evaluation | None = None
    ) -> Tensor: ...

    def rollout_loss(self, x: Tensor, states: Tensor, pred: Tensor) -> Tensor: ...

    def reduce(self, terms: Tensor) -> Tensor: ...

    def to_common(self, states: Tensor) -> Tensor: ...

    def compared(self, x: Tensor, pred: Tensor) -> tuple[Tensor, Tensor]: ...

    def run_title(self) -> str: ...

    def all_gather(self, data: Tensor) -> Any: ...  # Lightning's: a Tensor for a Tensor
