"""Lightning callbacks: the run config in every checkpoint, and evaluation steps run at the end of testing."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import lightning.pytorch as pl
import torch
from torch import Tensor

from omegaconf import DictConfig, OmegaConf

from encons import checkpoints, metrics, plots
from encons.data.simulate import simulate
from encons.errors import ConfigError
from encons.integrators import rollout
from encons.io import write_json

log = logging.getLogger(__name__)


class RunConfigInCheckpoints(pl.Callback):
    """Stores the resolved run ``config`` in every checkpoint (``checkpoints.CONFIG_KEY``); on a resume
    into a new run folder, carries the earlier run's best checkpoint over so that the best is chosen
    among all epochs (Lightning keeps only its path when the folder changes)."""

    def __init__(self, config: DictConfig):
        self.config = OmegaConf.to_container(config)

    def on_save_checkpoint(self, trainer: pl.Trainer, pl_module: pl.LightningModule, checkpoint: dict) -> None:
        checkpoint[checkpoints.CONFIG_KEY] = self.config

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        best = next((cb for cb in trainer.checkpoint_callbacks if cb.monitor), None)
        if trainer.ckpt_path is None or best is None:
            return
        state = checkpoints.read(trainer.ckpt_path, "ckpt_path")["callbacks"].get(best.state_key, {})
        old = Path(state.get("best_model_path") or "")
        if state.get("dirpath") == best.dirpath or not old.is_file() or state.get("best_model_score") is None:
            return
        new = Path(best.dirpath) / old.name
        if trainer.is_global_zero:
            new.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(old, new)
        trainer.strategy.barrier()
        best.best_model_path = best.kth_best_model_path = str(new)
        best.best_model_score = best.kth_value = state["best_model_score"]
        best.best_k_models = {str(new): state["best_model_score"]}


class SantosMetrics(pl.Callback):
    """The metrics of Santos, Ekal & Ventura §7, added to the test metrics (``test/…``) after testing.

    - ``mse_train`` / ``mse_test``: one-step configuration MSE, each state k ≥ max(2, ``history``) of every
      train / test trajectory predicted from the ``history`` states before it (the same targets for every
      model of history 1 or 2);
    - ``mse_integration``: configuration MSE of ``n_trajectories`` unforced (u = 0) initial conditions
      rolled out ``steps`` steps of the data dt from their first ``history`` true states;
    - ``energy_mse_integration``: per-trajectory MSE of the true energy along those rollouts against the
      initial energy (conserved without inputs), averaged over trajectories;
    - ``mass_mse``: MSE of the model's M(q) (its ``mass``) against the true M along the true integration
      trajectories; only for models with a ``mass`` network in the system's generalised coordinates.

    The integration trajectories come from ``seed`` (not the data seed), simulated as the data are.
    Also saves ``figures/integration.png`` (configuration and energy against time).
    """

    def __init__(self, n_trajectories: int = 16, steps: int = 500, seed: int = 1):
        if n_trajectories < 1 or steps < 2:
            raise ConfigError(f"callbacks.santos.n_trajectories={n_trajectories}; allowed: >= 1 and "
                              f"callbacks.santos.steps={steps} >= 2")
        self.n_trajectories, self.steps, self.seed = n_trajectories, steps, seed

    def on_test_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        model, system, data = module.model, module.system, trainer.datamodule
        if not system.known_physics:
            return
        was_training = model.training
        model.eval()
        with torch.no_grad():
            results = {f"mse_{split}": self.one_step_mse(module, data.arrays[split]) for split in ("train", "test")}
            results.update(self.integration(module, data.substeps))
        model.train(was_training)
        module.test_metrics.update(results)
        for logger in trainer.loggers:
            logger.log_metrics({f"test/{k}": v for k, v in results.items()})
        if module.output_dir is not None and trainer.is_global_zero:
            write_json(module.output_dir / "test_metrics.json", module.test_metrics)

    @staticmethod
    def one_step_mse(module: pl.LightningModule, arrays: dict[str, Tensor]) -> float:
        states, u, history, n = arrays["states"], arrays.get("u"), module.model.history, module.model.n
        windows = one_step_windows(states, history)
        batch = {"states": windows.to(module.device)}
        if u is not None:
            batch["u"] = one_step_windows(u, history).to(module.device)
        pred = module.predict(batch)[:, -1, :n]
        return metrics.configuration_mse(pred.double().cpu(), windows[:, -1, :n].double()).item()

    def integration(self, module: pl.LightningModule, substeps: int) -> dict[str, float]:
        model, system = module.model, module.system
        t = torch.arange(self.steps + 1, dtype=torch.float64) * module.dt
        s0 = system.sample_initial(self.n_trajectories, torch.Generator().manual_seed(self.seed))
        true = system.to_chart(simulate(system, s0, t, substeps), system.base_chart, model.chart)
        start = true[:, 0] if model.history == 1 else true[:, : model.history]
        u = torch.zeros(self.n_trajectories, len(t), system.n_controls) if system.n_controls else None
        dtype = next(model.parameters()).dtype
        pred = rollout(model, start.to(module.device, dtype), t.to(module.device, dtype), module.integrator,
                       None if u is None else u.to(module.device, dtype)).double().cpu()
        n = model.n
        energy_pred, energy_true = system.energy(pred, model.chart), system.energy(true, model.chart)
        out = {"mse_integration": metrics.configuration_mse(pred[..., :n], true[..., :n]).item(),
               "energy_mse_integration": metrics.energy_mse(energy_pred, energy_true[:, :1]).item()}
        if isinstance(getattr(model, "mass", None), torch.nn.Module) and model.chart == system.base_chart:
            q = true[..., :n]
            learned = model.mass(q.to(module.device, dtype)).double().cpu()
            out["mass_mse"] = metrics.mass_matrix_mse(learned, system.mass_matrix(q)).item()
        if module.output_dir is not None:
            self.figure(module, t, pred, true, energy_pred, energy_true)
        return out

    @staticmethod
    def figure(module, t: Tensor, pred: Tensor, true: Tensor, energy_pred: Tensor, energy_true: Tensor) -> None:
        fig, (ax_q, ax_e) = plots.subplots(1, 2, figsize=(10, 3.8))
        for d in range(module.model.n):
            line, = ax_q.plot(t, true[0, :, d], lw=1.4, label=f"q{d + 1} truth")
            ax_q.plot(t, pred[0, :, d], "--", color=line.get_color(), lw=1.1, label=f"q{d + 1} model")
        ax_q.set_xlabel("time (s)")
        ax_q.set_ylabel(f"configuration ({module.model.chart} chart; rad or m)")
        ax_q.set_title("unforced integration, trajectory 0", fontsize=9)
        ax_q.legend(fontsize=7)
        ax_e.plot(t, energy_true[0], lw=1.4, label="truth")
        ax_e.plot(t, energy_pred[0], "--", lw=1.1, label="model")
        ax_e.set_xlabel("time (s)")
        ax_e.set_ylabel("true energy E (J)")
        ax_e.set_title("energy along the integration, trajectory 0", fontsize=9)
        ax_e.legend(fontsize=7)
        fig.suptitle(module.run_title())
        path = plots._save(fig, module.output_dir / "figures" / "integration.png")
        plots.log_figures(module.logger, [path])


def one_step_windows(values: Tensor, history: int) -> Tensor:
    """The windows of ``history`` + 1 steps of ``values`` (N, T, d) whose last step k is ≥ max(2, history),
    flattened over trajectories: (N · (T − max(2, history)), history + 1, d)."""
    first = max(0, 2 - history)  # window s predicts step s + history
    return values.unfold(1, history + 1, 1)[:, first:].movedim(-1, -2).flatten(0, 1)
