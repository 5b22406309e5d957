"""The one LightningModule that trains any model on any system.

The objective is one of ``encons.objectives`` (rollout, derivative, acceleration, residual), chosen
among those the model lists in ``objectives``. An optional regulariser adds a weighted penalty;
optimiser and scheduler are the ``_partial_`` configs of ``conf/optimizer`` and ``conf/scheduler``. Batches are dicts (see ``encons.data.datamodule``): ``states`` and, where
present, inputs ``u``, ``rates`` and frames ``obs``.
The ``observation`` (``encons.models.observation``) maps the batch entry it reads to the states the
model rolls out, and adds its own loss terms: the identity by default; with an autoencoder the
rollout objective acts on encoded latent states, the regulariser on the latent field at them, and
validation and test compare decoded frames with the true ones (pixel MSE, frames, latent portraits).
"""

from __future__ import annotations

import inspect
import logging
from functools import partial
from pathlib import Path
from typing import Any, Callable

import lightning.pytorch as pl
import torch
from torch import Tensor
from torch.optim import Optimizer

from encons import checkpoints, metrics, plots
from encons.errors import ConfigError, DivergenceError
from encons.integrators import Integrator, rollout
from encons.io import save_npz, write_json
from encons.models.base import DynamicsModel
from encons.models.observation import Observation
from encons.objectives import OBJECTIVES
from encons.systems.base import System

log = logging.getLogger(__name__)
Regulariser = Callable[[DynamicsModel, Tensor, Tensor | None], Tensor]
Batch = dict[str, Tensor]


class TrainingModule(pl.LightningModule):
    """Trains ``model`` on windows of ``system`` trajectories sampled every ``dt``."""

    def __init__(self, model: DynamicsModel, system: System, dt: float, integrator: Integrator,
                 optimizer: Callable[..., Optimizer] | None = None, scheduler: Callable[..., Any] | None = None,
                 objective: str | None = None, regulariser: Regulariser | None = None,
                 horizon: int = 4, output_dir: str | None = None, observation: Observation | None = None,
                 model_name: str | None = None):
        super().__init__()
        self.model_name = model_name  # the model's config name (hnn_angle, not the class HNN) for titles
        objective = objective or model.objectives[0]
        self.observation = observation if observation is not None else Observation()
        if self.observation.objectives is not None and objective not in self.observation.objectives:
            raise ConfigError(f"objective={objective} does not apply to observation={type(self.observation).__name__}; "
                              f"allowed: {', '.join(self.observation.objectives)}")
        if objective not in model.objectives:
            raise ConfigError(f"objective={objective} does not apply to {type(model).__name__}; "
                              f"allowed: {', '.join(model.objectives)}")
        self.model, self.system, self.dt, self.integrator = model, system, dt, integrator
        self.optimizer = optimizer or partial(torch.optim.AdamW, lr=1e-3, weight_decay=1e-2)
        self.scheduler = scheduler
        self.objective, self.regulariser, self.horizon = objective, regulariser, horizon
        self.output_dir = Path(output_dir) if output_dir else None
        self.test_metrics: dict[str, float] = {}
        self._test_batches: list[tuple[Tensor, ...]] = []

    def times(self, length: int, like: Tensor) -> Tensor:
        return torch.arange(length, dtype=like.dtype, device=like.device) * self.dt

    def observe(self, batch: Batch) -> tuple[Tensor, Tensor]:
        """The observations of a batch (its ``observation.key`` entry) and the states they encode to."""
        x = batch[self.observation.key]
        return x, self.observation.encode(x)

    def predict(self, batch: Batch, states: Tensor | None = None) -> Tensor:
        """Roll out from the first state (``history`` states) of each window's (encoded) states over the
        window's length T: (N, T, 2n)."""
        x, states = (batch[self.observation.key], states) if states is not None else self.observe(batch)
        history = self.model.history
        start = states[:, 0] if history == 1 else states[:, :history]
        return rollout(self.model, start, self.times(x.shape[1], states), self.integrator, batch.get("u"))

    def rollout_loss(self, x: Tensor, states: Tensor, pred: Tensor) -> Tensor:
        """L1 of the rollout against the (encoded) states, summed over the window, plus the observation's terms."""
        return (pred[:, : states.shape[1]] - states).abs().sum((-1, -2)).mean() + self.observation.loss(x, states, pred)

    def to_common(self, states: Tensor) -> Tensor:
        return self.system.to_chart(states, self.model.chart, self.system.common_chart)

    def loss(self, batch: Batch) -> Tensor:
        """The run's objective (``encons.objectives``) on a batch of windows."""
        return OBJECTIVES[self.objective](self, batch)

    def training_step(self, batch: Batch, batch_idx: int) -> Tensor:
        u, size = batch.get("u"), len(batch["states"])
        loss = self.loss(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=size)
        if self.regulariser is not None:  # at the (encoded) states, detached: it shapes the field, not the encoder
            with torch.no_grad():
                points = self.observe(batch)[1]
            u = None if u is None else u[:, : points.shape[1]]
            penalty = self.regulariser(self.model, points.flatten(0, 1), None if u is None else u.flatten(0, 1))
            self.log("train/regulariser", penalty, batch_size=size)
            loss = loss + penalty
        if not torch.isfinite(loss):
            raise DivergenceError(
                f"training diverged: loss is {loss.item()} at epoch {self.current_epoch}, step "
                f"{self.global_step}; {self._kept_checkpoint()}; allowed: a lower optimizer.lr (or a larger model.mass_eps / model.damping where the model has one)")
        return loss

    def _kept_checkpoint(self) -> str:
        """What a diverged run leaves to resume from, said truthfully."""
        # the "last" callback (monitor null, filename last) records its file as best_model_path;
        # last_model_path is set only by save_last=True
        paths = [path for cb in self.trainer.checkpoint_callbacks
                 for path in (cb.last_model_path, cb.best_model_path if cb.monitor is None else "")]
        kept = [Path(p) for p in paths if p and Path(p).is_file()]
        if not kept:
            return "no checkpoint was written before it (none to resume from)"
        epoch = checkpoints.read(kept[0]).get("epoch")
        return f"{kept[0]} holds the last good weights (epoch {epoch}); resume with ckpt_path=last"

    def compared(self, x: Tensor, pred: Tensor) -> tuple[Tensor, Tensor]:
        """Prediction and truth where metrics compare them: states in the system's common chart, or
        decoded against true observations (frames flattened to vectors)."""
        if self.observation.identity:
            return self.to_common(pred), self.to_common(x)
        return self.observation.decode(pred).flatten(2), x.flatten(2)

    def validation_step(self, batch: Batch, batch_idx: int) -> None:
        x, states = self.observe(batch)
        pred = self.predict(batch, states)
        tre = metrics.trajectory_relative_error(*self.compared(x, pred), self.horizon)
        size = states.shape[0]
        self.log("val/loss", self.rollout_loss(x, states, pred), batch_size=size, sync_dist=True)
        self.log("val/traj_rel_err", tre.mean(), prog_bar=True, batch_size=size, sync_dist=True)

    def test_step(self, batch: Batch, batch_idx: int) -> None:
        x, states = self.observe(batch)
        pred = self.predict(batch, states)
        kept = (x, pred) if self.observation.identity else (x, states, pred)
        self._test_batches.append(tuple(p.detach() for p in kept))

    def _gathered(self) -> list[Tensor]:
        """The test batches concatenated; under DDP, every process's share."""
        parts = [torch.cat(p) for p in zip(*self._test_batches)]
        self._test_batches.clear()
        if self.trainer.world_size > 1:  # DDP: each process rolled out its share of the test set
            parts = [self.all_gather(p).flatten(0, 1) for p in parts]
        return parts

    def on_test_epoch_end(self) -> None:
        if not self.observation.identity:
            return self._test_observations(*self._gathered())
        true, pred = (p.double() for p in self._gathered())
        energy = (lambda x: self.system.energy(x, self.model.chart)) if self.system.known_physics else None
        if energy is None:
            log.info("energy metrics skipped: system '%s' has no known energy", self.system.name)
        energies = [energy(x) for x in (pred, true)] if energy else None
        true_c, pred_c = self.to_common(true), self.to_common(pred)
        self.test_metrics = metrics.summarise(pred_c, true_c, *(energies or (None, None)), horizon=self.horizon)
        scalars, curves = metrics.long_rollout_errors(true, pred, self.trainer.datamodule.states["train"].to(true),
                                                      self.dt, self.to_common, energy, self.horizon)
        self.test_metrics.update(scalars)
        log.info("%s", metrics.curves_table(self.times(true.shape[1], true), curves))
        self.log_dict({f"test/{k}": v for k, v in self.test_metrics.items()}, sync_dist=True)
        if self.output_dir is not None and self.trainer.is_global_zero:
            write_json(self.output_dir / "test_metrics.json", self.test_metrics)
            units = self.system.units(self.system.common_chart)
            figures = plots.mse_figure(self.times(true.shape[1], true).cpu(), curves, self.output_dir / "figures",
                                       title=self.run_title(), units=units)
            curves = {"t": self.times(true.shape[1], true).cpu().numpy(),
                      "rel_err": metrics.relative_error(pred_c, true_c).cpu().numpy(),
                      **{f"{k}_{name}": v.cpu().numpy() for name, c in curves.items() for k, v in c.items()}}
            if energies:
                curves["energy_err"] = metrics.energy_abs_error(*energies).cpu().numpy()
            save_npz(self.output_dir / "test_curves.npz", **curves)
            linear = metrics.fit_linear_ode(self.trainer.datamodule.states["train"].to(true), self.dt)
            baseline = self.to_common(metrics.linear_ode_rollout(linear, true[:, 0], self.times(true.shape[1], true)))
            figures += plots.rollout_figures(self.times(true.shape[1], true).cpu(), pred_c.cpu(), true_c.cpu(),
                                         [e.cpu() for e in energies] if energies else None,
                                         self.output_dir / "figures", title=self.run_title(), units=units,
                                         baseline=baseline.cpu())
            plots.log_figures(self.logger, figures)

    def _test_observations(self, x: Tensor, states: Tensor, pred: Tensor) -> None:
        """Test metrics and figures of a run seen through an observation model: pixel MSE of decoded
        predictions against the true frames over time, the latent phase portrait, predicted vs true frames."""
        frames = self.observation.decode(pred).double()
        x = x.double()
        mse = (frames - x).square().mean((-1, -2))                                       # (N, T)
        t = self.times(x.shape[1], x).cpu()
        tre = metrics.trajectory_relative_error(frames.flatten(2), x.flatten(2), self.horizon)
        finite = torch.isfinite(mse).all(-1)
        self.test_metrics = {"traj_rel_err": tre.mean().item(), "traj_rel_err_std": tre.std().item(),
                             "pixel_mse": mse.mean().item(), "pixel_mse_final": mse[:, -1].mean().item(),
                             "pixel_mse_final_median": mse[:, -1].median().item(),
                             "diverged": 1.0 - finite.double().mean().item()}
        log.info("pixel MSE of predicted frames: %s", ", ".join(
            f"t={t[k]:.0f}: {mse[:, k].mean().item():.4g}" for k in sorted({0, len(t) // 4, len(t) // 2, len(t) - 1})))
        self.log_dict({f"test/{k}": v for k, v in self.test_metrics.items()}, sync_dist=True)
        if self.output_dir is None or not self.trainer.is_global_zero:
            return
        write_json(self.output_dir / "test_metrics.json", self.test_metrics)
        save_npz(self.output_dir / "test_curves.npz", t=t.numpy(), pixel_mse=mse.cpu().numpy(),
                 rel_err=metrics.relative_error(frames.flatten(2), x.flatten(2)).cpu().numpy(),
                 latent_pred=pred.cpu().numpy(), latent_encoded=states.cpu().numpy())
        out, title = self.output_dir / "figures", self.run_title()
        figures = plots.pixel_mse_figure(t, mse.cpu(), out, title)
        figures += plots.latent_phase_figure(pred.detach().cpu(), states.detach().cpu(), out, title)
        figures += plots.frames_figure(t, frames.cpu(), x.cpu(), out, title)
        plots.log_figures(self.logger, figures)

    def run_title(self) -> str:
        """Figure title: model (+ regulariser, e.g. ``NODE + C_H``) on system (chart or observation)."""
        model = self.model_name or type(self.model).__name__
        if self.regulariser is not None:
            model += f" + {getattr(self.regulariser, 'label', type(self.regulariser).__name__)}"
        if not self.observation.identity:
            return (f"{model} on {self.system.name} ({type(self.observation).__name__}, "
                    f"latent size {2 * self.model.n})")
        return f"{model} on {self.system.name} ({self.model.chart} chart)"

    def configure_optimizers(self):
        """The ``optimizer`` partial on the parameters, and the ``scheduler`` partial on it (if any).

        A scheduler that takes ``total_steps`` gets Lightning's estimate for ``max_epochs`` and steps per
        optimiser step (a run stopped by ``max_time`` or ``max_steps`` ends before its decay does);
        ``ReduceLROnPlateau`` steps each epoch on ``val/loss``; any other scheduler each epoch.
        """
        opt = self.optimizer(self.parameters())
        if self.scheduler is None:
            return opt
        if takes_total_steps(self.scheduler):
            sched = self.scheduler(opt, total_steps=max(1, int(self.trainer.estimated_stepping_batches)))
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
        sched = self.scheduler(opt)
        if isinstance(sched, torch.optim.lr_scheduler.ReduceLROnPlateau):
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": "val/loss"}}
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched}}


def takes_total_steps(scheduler: Callable[..., Any]) -> bool:
    """Whether a scheduler (class or partial of one) takes ``total_steps`` (per-step schedules)."""
    func = scheduler.func if isinstance(scheduler, partial) else scheduler
    return "total_steps" in inspect.signature(func).parameters
