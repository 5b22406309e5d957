"""Lightning callbacks: a per-epoch progress line, and evaluation steps run at the end of testing."""

from __future__ import annotations

import logging
import sys
import time

import lightning.pytorch as pl
import torch
from torch import Tensor

from encons import metrics, plots
from encons.data.simulate import simulate
from encons.errors import ConfigError
from encons.integrators import rollout
from encons.io import write_json
from encons.report import duration, to_log_files

log = logging.getLogger(__name__)


class EpochLine(pl.Callback):
    """One line per training epoch — ``epoch k of N: train/loss …, val/… …, elapsed, ETA`` — in the run's
    log files (``train.log``), and on the console too when stdout is not a terminal (a job's output file,
    where the progress bar does not draw) and the run shows progress (``trainer.enable_progress_bar``).
    The ETA assumes the remaining epochs (``trainer.max_epochs``) take as long as the past ones."""

    def __init__(self, metrics: tuple[str, ...] = ("train/loss", "val/loss")):
        self.metrics = tuple(metrics)

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.started, self.first_epoch = time.perf_counter(), trainer.current_epoch

    def on_train_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        done = trainer.current_epoch + 1
        total = trainer.max_epochs if trainer.max_epochs and trainer.max_epochs > 0 else None
        elapsed = time.perf_counter() - self.started
        monitor = trainer.checkpoint_callback.monitor if trainer.checkpoint_callback is not None else None
        keys = (*self.metrics, monitor or "val/traj_rel_err")
        shown = [f"{k} {float(trainer.callback_metrics[k]):.4g}" for k in dict.fromkeys(keys)
                 if k in trainer.callback_metrics]
        eta = (f", ETA {duration(elapsed / (done - self.first_epoch) * (total - done))}"
               if total and done > self.first_epoch else "")
        line = (f"epoch {done}{f' of {total}' if total else ''} (step {trainer.global_step}): {', '.join(shown)}, "
                f"elapsed {duration(elapsed)}{eta}")
        if trainer.progress_bar_callback is not None and not sys.stdout.isatty():
            log.info(line)              # console and log files
        else:
            to_log_files(line)          # the log files only: the progress bar shows it live


class SantosMetrics(pl.Callback):
    """The metrics of Santos, Ekal & Ventura §7, added to the test metrics (``test/…``) after testing.

    - ``mse_train`` / ``mse_test``: one-step configuration MSE, each state k ≥ 2 of every train / test
      trajectory predicted from the ``history`` states before it (the same targets for every model);
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
        windows = states.unfold(1, history + 1, 1)[:, 2 - history:].movedim(-1, -2).flatten(0, 1)
        dtype = next(module.model.parameters()).dtype  # test states are float64, the model need not be
        batch = {"states": windows.to(module.device, dtype)}
        if u is not None:
            batch["u"] = u.unfold(1, history + 1, 1)[:, 2 - history:].movedim(-1, -2).flatten(0, 1).to(module.device, dtype)
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
        plt = plots.plt
        fig, (ax_q, ax_e) = plt.subplots(1, 2, figsize=(10, 3.8))
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
