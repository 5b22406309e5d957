"""The one LightningModule that trains any model on any system.

Objectives: ``rollout`` (Zhong et al. §4.1: L1 loss summed over a window rolled out from its
first state, or first ``model.history`` states), ``derivative`` (Lim & Kasim eq. (2): squared
error of the field against the state derivatives the data module pairs with the states),
``acceleration`` (Xiao et al. §3: the same on the q̈ half only) or
``residual`` (the squared norm of a discrete model's own residual, e.g. SyMo's DEL equations).
A model lists the objectives it supports in ``objectives``. An optional regulariser adds a
weighted penalty. Batches are dicts (see ``encons.data.datamodule``): ``states`` and, where
present, inputs ``u``, ``rates`` and frames ``obs``.
The ``observation`` (``encons.models.observation``) maps the batch entry it reads to the states the
model rolls out, and adds its own loss terms: the identity by default; with an autoencoder the
rollout objective acts on encoded latent states, the regulariser on the latent field at them, and
validation and test compare decoded frames with the true ones (pixel MSE, frames, latent portraits).
"""

from __future__ import annotations

import math
import logging
from pathlib import Path
from typing import Callable

import lightning.pytorch as pl
import torch
from torch import Tensor

from encons import metrics, plots
from encons.errors import ConfigError, DivergenceError
from encons.evaluation import Evaluation
from encons.integrators import Integrator, rollout, state_derivative
from encons.io import save_npz, write_json
from encons.models.base import DynamicsModel
from encons.models.observation import Observation
from encons.systems.base import System

log = logging.getLogger(__name__)
OBJECTIVES = ("rollout", "derivative", "acceleration", "residual")
SCHEDULERS = (None, "cosine", "onecycle", "plateau")
Regulariser = Callable[[DynamicsModel, Tensor, Tensor | None], Tensor]
Batch = dict[str, Tensor]


class DynamicsModule(pl.LightningModule):
    """Trains ``model`` on windows of ``system`` trajectories sampled every ``dt``."""

    def __init__(self, model: DynamicsModel, system: System, dt: float, integrator: Integrator,
                 lr: float = 1e-3, weight_decay: float = 1e-2, scheduler: str | None = None, warmup: float = 0.0,
                 patience: int = 50, factor: float = 0.7,
                 objective: str | None = None, regulariser: Regulariser | None = None,
                 horizon: int = 4, output_dir: str | None = None, observation: Observation | None = None,
                 model_name: str | None = None, evaluation: Evaluation | None = None):
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
        if scheduler not in SCHEDULERS:
            raise ConfigError(f"optim.scheduler={scheduler!r} is unknown; allowed: {', '.join(map(str, SCHEDULERS))}")
        if not 0 <= warmup < 1:
            raise ConfigError(f"optim.warmup={warmup} must lie in [0, 1): the fraction of steps warming up")
        if patience < 0 or not 0 < factor < 1:
            raise ConfigError(f"optim.patience={patience}; allowed: >= 0 and optim.factor={factor} in (0, 1)")
        if lr <= 0:
            raise ConfigError(f"optim.lr={lr}; allowed: > 0")
        self.model, self.system, self.dt, self.integrator = model, system, dt, integrator
        self.lr, self.weight_decay, self.scheduler_name, self.warmup = lr, weight_decay, scheduler, warmup
        self.patience, self.factor = patience, factor
        self.objective, self.regulariser, self.horizon = objective, regulariser, horizon
        self.evaluation = evaluation or Evaluation()  # test rollouts: their own integrator (encons.evaluation)
        self.output_dir = Path(output_dir) if output_dir else None
        self.test_metrics: dict[str, float] = {}
        self._test_batches: list[tuple[Tensor, ...]] = []

    def times(self, length: int, like: Tensor) -> Tensor:
        return torch.arange(length, dtype=like.dtype, device=like.device) * self.dt

    def encode(self, batch: Batch) -> tuple[Tensor, Tensor]:
        """The observations of a batch (its ``observation.key`` entry) and the states they encode to."""
        x = batch[self.observation.key]
        return x, self.observation.encode(x)

    def predict(self, batch: Batch, states: Tensor | None = None, evaluation: Evaluation | None = None) -> Tensor:
        """Roll out from the first state (``history`` states) of each window's (encoded) states over the
        window's length T: (N, T, 2n); by ``evaluation`` if given, else by the training integrator."""
        x, states = (batch[self.observation.key], states) if states is not None else self.encode(batch)
        history = self.model.history
        start = states[:, 0] if history == 1 else states[:, :history]
        if evaluation is not None:
            return evaluation.rollout(self.model, start, self.times(x.shape[1], states), batch.get("u"))
        return rollout(self.model, start, self.times(x.shape[1], states), self.integrator, batch.get("u"))

    def rollout_loss(self, x: Tensor, states: Tensor, pred: Tensor) -> Tensor:
        """L1 of the rollout against the (encoded) states, summed over the window, plus the observation's terms."""
        return (pred[:, : states.shape[1]] - states).abs().sum((-1, -2)).mean() + self.observation.loss(x, states, pred)

    def to_common(self, states: Tensor) -> Tensor:
        return self.system.to_chart(states, self.model.chart, self.system.common_chart)

    def loss(self, batch: Batch) -> Tensor:
        """The objective on a batch of windows (see the module docstring)."""
        x, states = self.encode(batch)
        u = batch.get("u")
        if self.objective == "rollout":
            return self.rollout_loss(x, states, self.predict(batch, states))
        if self.objective == "residual":
            return (self.model.residual(states, self.times(states.shape[1], states), u) ** 2).sum(-1).mean()
        if "rates" not in batch:
            raise ConfigError(f"objective={self.objective} needs batches with rates; allowed: a data module built "
                              f"with objective='{self.objective}' (data.objective: ${{objective}})")
        error = state_derivative(self.model, states, u) - batch["rates"]
        if self.objective == "acceleration":  # q̈ only
            error = error[..., error.shape[-1] // 2:]
        return (error**2).sum(-1).mean()

    def training_step(self, batch: Batch, batch_idx: int) -> Tensor:
        u, size = batch.get("u"), len(batch["states"])
        loss = self.loss(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=size)
        if self.regulariser is not None:  # at the (encoded) states, detached: it shapes the field, not the encoder
            with torch.no_grad():
                points = self.encode(batch)[1]
            u = None if u is None else u[:, : points.shape[1]]
            penalty = self.regulariser(self.model, points.flatten(0, 1), None if u is None else u.flatten(0, 1))
            self.log("train/regulariser", penalty, batch_size=size)
            loss = loss + penalty
        if not torch.isfinite(loss):
            raise DivergenceError(
                f"training diverged: loss is {loss.item()} at epoch {self.current_epoch}, step "
                f"{self.global_step}; {self._kept_checkpoint()}; allowed: a lower optim.lr (or a larger model.mass_eps / model.damping where the model has one)")
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
        epoch = torch.load(kept[0], map_location="cpu", weights_only=False, mmap=True).get("epoch")
        return f"{kept[0]} holds the last good weights (epoch {epoch}); resume with ckpt_path=last"

    def compared(self, x: Tensor, pred: Tensor) -> tuple[Tensor, Tensor]:
        """Prediction and truth where metrics compare them: states in the system's common chart, or
        decoded against true observations (frames flattened to vectors)."""
        if self.observation.identity:
            return self.to_common(pred), self.to_common(x)
        return self.observation.decode(pred).flatten(2), x.flatten(2)

    def validation_step(self, batch: Batch, batch_idx: int) -> None:
        x, states = self.encode(batch)
        pred = self.predict(batch, states)
        tre = metrics.trajectory_relative_error(*self.compared(x, pred), self.horizon)
        size = states.shape[0]
        self.log("val/loss", self.rollout_loss(x, states, pred), batch_size=size, sync_dist=True)
        self.log("val/traj_rel_err", tre.mean(), prog_bar=True, batch_size=size, sync_dist=True)

    def test_step(self, batch: Batch, batch_idx: int) -> None:
        x, states = self.encode(batch)
        pred = self.predict(batch, states, self.evaluation)
        if not self.observation.identity:
            return self._test_batches.append(tuple(p.detach() for p in (x, states, pred.to(states.dtype))))
        oracle = (self.evaluation.oracle(self.system, self.model.chart, x[:, 0], self.times(x.shape[1], x), batch.get("u"))
                  if self.system.known_physics else None)  # the floor: the true field, same starts and integrator
        self._test_batches.append(tuple(p.detach() for p in (x, pred) + ((oracle,) if oracle is not None else ())))

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
        true, pred, *oracle = (p.double() for p in self._gathered())
        energy = (lambda x: self.system.energy(x, self.model.chart)) if self.system.known_physics else None
        if energy is None:
            log.info("energy metrics skipped: system '%s' has no known energy", self.system.name)
        energies = [energy(x) for x in (pred, true)] if energy else None
        true_c, pred_c = self.to_common(true), self.to_common(pred)
        score = dict(horizon=self.horizon, dt=self.dt, vpt_threshold=self.evaluation.vpt_threshold)
        self.test_metrics = metrics.summarise(pred_c, true_c, *(energies or (None, None)), **score)
        scalars, curves = metrics.long_rollout_errors(true, pred, self.trainer.datamodule.states["train"].to(true),
                                                      self.dt, self.to_common, energy, self.horizon)
        self.test_metrics.update(scalars)
        if oracle:  # the floor, scored by the same metrics
            floor = metrics.summarise(self.to_common(oracle[0]), true_c, energy(oracle[0]) if energy else None,
                                      energies[1] if energies else None, **score)
            self.test_metrics.update({f"oracle/{k}": v for k, v in floor.items()})
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
            figures += plots.test_figures(self.times(true.shape[1], true).cpu(), pred_c.cpu(), true_c.cpu(),
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
        """AdamW at ``lr``, optionally scheduled per optimiser step over the whole run.

        ``cosine``: linear warm-up from 0 over the first ``warmup`` fraction of steps, then cosine
        decay to 0. ``onecycle``: torch's ``OneCycleLR`` peaking at ``lr`` after ``warmup`` of the
        steps (0: its default 0.3), momentum cycled. The step count is Lightning's estimate for
        ``max_epochs``; a run stopped by ``max_time`` or ``max_steps`` ends before the decay does.
        ``plateau``: ``ReduceLROnPlateau`` on ``val/loss`` each epoch (``patience``, ``factor``).
        """
        opt = torch.optim.AdamW(self.parameters(), lr=self.lr, weight_decay=self.weight_decay)
        if self.scheduler_name is None:
            return opt
        if self.scheduler_name == "plateau":  # on the validation loss, every epoch (Santos et al. §7)
            sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, patience=self.patience, factor=self.factor)
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": "val/loss"}}
        total = max(1, int(self.trainer.estimated_stepping_batches))
        if self.scheduler_name == "onecycle":
            sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=self.lr, total_steps=total,
                                                        pct_start=self.warmup or 0.3)
        else:
            warm = int(self.warmup * total)
            sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda step: (step + 1) / warm if step < warm else
                                                      0.5 * (1 + math.cos(math.pi * (step - warm) / max(1, total - warm))))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
