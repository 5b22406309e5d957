"""The one LightningModule that trains any model on any system.

The objective is one of ``encons.training.objectives`` (rollout, derivative, acceleration, onestep, residual), chosen
among those the model lists in ``objectives``. An optional regulariser adds a weighted penalty;
optimiser and scheduler are the ``_partial_`` configs of ``conf/optimizer`` and ``conf/scheduler``. Batches are dicts
(see ``encons.data.datamodule``): ``states`` and, where present, inputs ``u``, ``rates`` and frames ``obs``. The
``observation`` (``encons.models.observation``) maps the batch entry it reads to the states the model rolls out, and
adds its own loss terms: the identity by default; with an autoencoder the rollout objective acts on encoded latent
states, the regulariser on the latent field at them, and validation compares decoded frames with the true ones. Testing
feeds the ``evaluators`` (``encons.evaluators``), which score; ``encons.training.callbacks.TestResults`` writes what
they scored.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Mapping
from functools import partial
from pathlib import Path
from typing import Any, Callable, cast

import lightning.pytorch as pl
import numpy as np
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from torch import Tensor
from torch.optim import Optimizer

from encons.evaluators.base import Evaluator, TestBatch
from encons.infra import checkpoints
from encons.infra.errors import ConfigError, DivergenceError
from encons.models.base import DynamicsModel
from encons.models.observation import Observation
from encons.numerics import metrics
from encons.numerics.evaluation import Evaluation
from encons.numerics.integrators import Integrator, rollout
from encons.systems.base import System
from encons.training.objectives import OBJECTIVES

log = logging.getLogger(__name__)
Regulariser = Callable[[DynamicsModel, Tensor, Tensor | None], Tensor]
Batch = dict[str, Tensor]


class TrainingModule(pl.LightningModule):
    """Trains ``model`` on windows of ``system`` trajectories sampled every ``dt``; tests by ``evaluators``
    (name → ``encons.evaluators.Evaluator``; none: testing scores nothing), each checked against the run here.
    ``recorded``: facts of the run reported beside the scores (``plain_inverse``, ``encons.training.attempts``).
    Objectives and evaluators see it as an ``encons.numerics.learner.Learner``; its arguments come checked
    (``encons.config.check.validate``), so it does not check them again."""

    def __init__(
        self,
        model: DynamicsModel,
        system: System,
        dt: float,
        integrator: Integrator,
        optimizer: Callable[..., Optimizer] | None = None,
        scheduler: Callable[..., Any] | None = None,
        objective: str | None = None,
        regulariser: Regulariser | None = None,
        horizon: int = 4,
        observation: Observation | None = None,
        model_name: str | None = None,
        evaluation: Evaluation | None = None,
        evaluators: Mapping[str, Evaluator] | None = None,
        recorded: Mapping[str, float] | None = None,
        validation: str = "rollout",
    ):
        super().__init__()
        self.model_name = model_name  # the model's config name (hnn_angle, not the class HNN) for titles
        objective = objective or model.objectives[0]  # checked against model and observation by encons.config.check
        self.observation = observation if observation is not None else Observation()
        self.model, self.system, self.dt, self.integrator = model, system, dt, integrator
        self.optimizer = optimizer or partial(torch.optim.AdamW, lr=1e-3, weight_decay=1e-2)
        self.scheduler = scheduler
        self.objective, self.regulariser, self.horizon = objective, regulariser, horizon
        self.evaluation = evaluation or Evaluation()  # test rollouts: their own integrator (encons.numerics.evaluation)
        self.evaluators = dict(evaluators or {})
        for evaluator in self.evaluators.values():
            evaluator.check(self)
        self.recorded = dict(recorded or {})
        self.validation = validation  # validation.criterion: rollout | objective (none: Lightning runs no validation)
        self.test_metrics: dict[str, float] = {}
        self.test_curves: dict[str, np.ndarray] = {}  # per-step curves of the last test, saved beside the metrics

    def times(self, length: int, like: Tensor) -> Tensor:
        return torch.arange(length, dtype=like.dtype, device=like.device) * self.dt

    def observe(self, batch: Batch) -> tuple[Tensor, Tensor]:
        """The observations of a batch (its ``observation.key`` entry) and the states they encode to."""
        x = batch[self.observation.key]
        return x, self.observation.encode(x)

    def predict(self, batch: Batch, states: Tensor | None = None, evaluation: Evaluation | None = None) -> Tensor:
        """Roll out from the first state (``history`` states) of each window's (encoded) states over the
        window's length T: (N, T, 2n); by ``evaluation`` if given, else by the training integrator."""
        x, states = (batch[self.observation.key], states) if states is not None else self.observe(batch)
        history = self.model.history
        start = states[:, 0] if history == 1 else states[:, :history]
        if evaluation is not None:
            return evaluation.rollout(self.model, start, self.times(x.shape[1], states), batch.get("u"))
        return rollout(self.model, start, self.times(x.shape[1], states), self.integrator, batch.get("u"))

    def rollout_loss(self, x: Tensor, states: Tensor, pred: Tensor) -> Tensor:
        """L1 of the rollout against the (encoded) states, summed over the window, plus the observation's terms."""
        return self.reduce((pred[:, : states.shape[1]] - states).abs().sum((-1, -2))) + self.observation.loss(
            x, states, pred, self.reduce
        )

    def reduce(self, terms: Tensor) -> Tensor:
        """The batch mean of a loss's terms (leading axis: windows or points); ``encons.training.stacked`` means per
        member."""
        return terms.mean()

    def to_common(self, states: Tensor) -> Tensor:
        return self.system.to_chart(states, self.model.chart, self.system.common_chart)

    def loss(self, batch: Batch) -> Tensor:
        """The run's objective (``encons.training.objectives``) on a batch of windows."""
        return OBJECTIVES[self.objective](self, batch)

    def training_step(self, batch: Batch, batch_idx: int) -> Tensor:
        size = len(batch["states"])
        loss = self.loss(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=size, sync_dist=True)  # every rank's, not rank 0's
        penalty = self.penalty(batch)
        if penalty is not None:
            self.log("train/regulariser", penalty, batch_size=size)
            loss = loss + penalty
        if not torch.isfinite(loss):
            raise DivergenceError(
                f"training diverged: loss is {loss.item()} at epoch {self.current_epoch + 1}, step "
                f"{self.global_step}; {self._kept_checkpoint()}; allowed: a lower optimizer.lr (or a larger "
                f"model.mass_eps / model.guard where the model has one)"
            )
        return loss

    def penalty(self, batch: Batch) -> Tensor | None:
        """The regulariser's weighted penalty (None: no regulariser) at the batch's (encoded) states, detached:
        it shapes the field, not the encoder."""
        if self.regulariser is None:
            return None
        with torch.no_grad():
            points = self.observe(batch)[1]
        u = batch.get("u")
        u = None if u is None else u[:, : points.shape[1]].flatten(0, 1)
        return self.regularise(points.flatten(0, 1), u)

    def training_loss(self, batch: Batch) -> Tensor:
        """What a training step minimises: the objective plus the regulariser's penalty, if any."""
        penalty = self.penalty(batch)
        return self.loss(batch) if penalty is None else self.loss(batch) + penalty

    def regularise(self, points: Tensor, u: Tensor | None) -> Tensor:
        """The regulariser on the model at ``points`` (B, 2n) under inputs ``u`` (B, m) or None."""
        assert self.regulariser is not None  # called only for a run with a regulariser
        return self.regulariser(self.model, points, u)

    def _kept_checkpoint(self) -> str:
        """What a diverged run leaves to resume from, said truthfully."""
        # the "last" callback (monitor null, filename last) records its file as best_model_path;
        # last_model_path is set only by save_last=True
        paths = [
            path
            for cb in cast("list[ModelCheckpoint]", self.trainer.checkpoint_callbacks)  # encons' are ModelCheckpoints
            for path in (cb.last_model_path, cb.best_model_path if cb.monitor is None else "")
        ]
        kept = [Path(p) for p in paths if p and Path(p).is_file()]
        if not kept:
            return "no checkpoint was written before it (none to resume from)"
        epoch = cast(int, checkpoints.read(kept[0]).get("epoch"))  # Lightning writes it in every checkpoint
        return f"{kept[0]} holds the last good weights (epoch {epoch + 1}); resume with ckpt_path=last"

    def compared(self, x: Tensor, pred: Tensor) -> tuple[Tensor, Tensor]:
        """Prediction and truth where metrics compare them: states in the system's common chart, or
        decoded against true observations (frames flattened to vectors)."""
        if self.observation.identity:
            return self.to_common(pred), self.to_common(x)
        return self.observation.decode(pred).flatten(2), x.flatten(2)

    @property
    def compared_angles(self) -> Tensor | None:
        """The angle entries (bool (D,)) of what ``compared`` returns, which metrics compare on the circle."""
        return self.system.angle_entries(self.system.common_chart) if self.observation.identity else None

    def validation_step(self, batch: Batch, batch_idx: int) -> None:
        """``validation.criterion``: rollout (val/loss, the rollout's L1, and val/traj_rel_err) or objective
        (val/loss, the run's objective on the validation windows: a paper's own criterion, e.g. Santos et
        al.'s one-step MSE, Lim & Kasim's derivative loss)."""
        if self.validation == "objective":
            self.log("val/loss", self.loss(batch), prog_bar=True, batch_size=len(batch["states"]), sync_dist=True)
            return
        x, states = self.observe(batch)
        pred = self.predict(batch, states)
        tre = metrics.trajectory_relative_error(*self.compared(x, pred), self.horizon, self.compared_angles)
        size = states.shape[0]
        self.log("val/loss", self.rollout_loss(x, states, pred), batch_size=size, sync_dist=True)
        self.log("val/traj_rel_err", tre.mean(), prog_bar=True, batch_size=size, sync_dist=True)

    def on_test_epoch_start(self) -> None:
        self.model.reset_diagnostics()
        for evaluator in self.evaluators.values():
            evaluator.reset()

    def test_step(self, batch: Batch, batch_idx: int) -> None:
        """Feed the batch to every evaluator; the rollout they read is made once (``TestBatch.pred``)."""
        test_batch = TestBatch(self, batch)
        for evaluator in self.evaluators.values():
            evaluator.update(self, test_batch)

    def on_test_epoch_end(self) -> None:
        """Every evaluator's scores and the ``recorded`` facts, merged into ``test_metrics`` (and the curves
        into ``test_curves``) and logged as ``test/<name>``; ``encons.training.callbacks.TestResults`` saves them."""
        self.test_metrics, self.test_curves = {}, {}
        for name, evaluator in self.evaluators.items():
            result = evaluator.compute(self)
            merges: tuple[tuple[str, dict[str, Any], Mapping[str, Any]], ...] = (
                ("metric", self.test_metrics, result.metrics),
                ("curve", self.test_curves, result.curves),
            )
            for kind, merged, new in merges:
                if clash := sorted(set(merged) & set(new)):
                    raise ConfigError(
                        f"evaluators.{name} gives the {kind} {clash[0]!r} another evaluator of this "
                        f"run gives too; allowed: evaluators whose {kind} names differ"
                    )
                merged.update(new)
        self.test_metrics.update(self.recorded)
        self.log_dict({f"test/{k}": v for k, v in self.test_metrics.items()}, sync_dist=True)

    def run_title(self) -> str:
        """Figure title: model (+ regulariser, e.g. ``NODE + C_H``) on system (chart or observation)."""
        model = self.model_name or type(self.model).__name__
        if self.regulariser is not None:
            model += f" + {getattr(self.regulariser, 'label', type(self.regulariser).__name__)}"
        if not self.observation.identity:
            return f"{model} on {self.system.name} ({type(self.observation).__name__}, latent size {2 * self.model.n})"
        return f"{model} on {self.system.name} (learns in the {self.model.chart} chart)"

    def configure_optimizers(self):
        """The ``optimizer`` partial on the parameters, and the ``scheduler`` partial on it (if any).

        A scheduler that takes ``total_steps`` gets Lightning's estimate for ``max_epochs`` and steps per
        optimiser step (a run stopped by ``max_time`` or ``max_steps`` ends before its decay does);
        ``ReduceLROnPlateau`` steps after each validation (``validation.every``) on ``val/loss``; any other scheduler
        each epoch.
        """
        opt = self.optimizer(self.parameters())
        if self.scheduler is None:
            return opt
        if takes_total_steps(self.scheduler):
            sched = self.scheduler(opt, total_steps=max(1, int(self.trainer.estimated_stepping_batches)))
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
        sched = self.scheduler(opt)
        if isinstance(sched, torch.optim.lr_scheduler.ReduceLROnPlateau):
            return {
                "optimizer": opt,
                "lr_scheduler": {
                    "scheduler": sched,
                    "monitor": "val/loss",  # after each validation
                    "frequency": self.trainer.check_val_every_n_epoch,
                },
            }
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched}}


def takes_total_steps(scheduler: Callable[..., Any]) -> bool:
    """Whether a scheduler (class or partial of one) takes ``total_steps`` (per-step schedules)."""
    func = scheduler.func if isinstance(scheduler, partial) else scheduler
    return "total_steps" in inspect.signature(func).parameters
