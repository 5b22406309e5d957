"""The metrics of Santos, Ekal & Ventura §7 for controlled (and any known) systems."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import torch
from matplotlib.figure import Figure
from torch import Tensor

from encons.data.simulate import simulate
from encons.evaluators import figures
from encons.evaluators.base import Evaluator, Result
from encons.infra.bounds import Count, Declared, Range, Seed
from encons.infra.errors import ConfigError
from encons.numerics import metrics
from encons.numerics.integrators import rollout

if TYPE_CHECKING:
    from encons.models.base import DynamicsModel
    from encons.numerics.learner import Learner


class SantosMetrics(Evaluator, Declared):
    """Santos, Ekal & Ventura §7, on a system of known physics (none otherwise):

    - ``mse_train`` / ``mse_test``: one-step configuration MSE, each state k ≥ max(2, ``history``) of every
      train / test trajectory predicted from the ``history`` states before it (the same targets for every
      model of history 1 or 2);
    - ``mse_train_floor`` / ``mse_test_floor``: the same for the model's ``true_counterpart`` (the system's true
      dynamics stepped as the model steps: the true field by the training integrator, SyMo's DEL step with the
      true M and V), in float64: what the model's own discretisation leaves at best, beside what it scored
      (these metrics roll out by the training integrator, so each model has its own floor, not one oracle row);
    - ``mse_integration``: configuration MSE of ``n_trajectories`` unforced (u = 0) initial conditions
      rolled out ``steps`` steps of the data dt from their first ``history`` true states;
    - ``energy_mse_integration``: per-trajectory MSE of the true energy along those rollouts against the
      initial energy (conserved without inputs), averaged over trajectories;
    - the model's solver counters over those rollouts (``diagnostics``, e.g. ``newton_unconverged_integration``);
    - ``mass_mse``: MSE of the model's M(q) (its ``mass``) against the true M along the true integration
      trajectories; only for models with a ``mass`` network in the system's generalised coordinates.

    Every rollout here is by the training integrator, as the paper tests. The integration trajectories
    come from ``seed`` (not the data seed), simulated as the data are. Figure: ``integration``.
    """

    headline = (  # the benchmark summary's headline columns (encons.tools.report)
        "mse_train",
        "mse_test",
        "mse_test_floor",
        "mse_integration",
        "energy_mse_integration",
        "mass_mse",
        "newton_unconverged_integration",
    )

    config_key = "evaluators.santos"

    def __init__(self, n_trajectories: Count = 16, steps: Annotated[int, Range(ge=2)] = 500, seed: Seed = 1):
        self.n_trajectories, self.steps, self.seed = n_trajectories, steps, seed

    def check(self, module: Learner) -> None:
        if not module.observation.identity:
            raise ConfigError(
                f"evaluators.santos does not apply to observation={type(module.observation).__name__} "
                f"(§7's metrics are on the system's states); allowed: evaluators=[pixels]"
            )

    def compute(self, module: Learner) -> Result:
        self.drawn: tuple[Tensor, Tensor, Tensor, Tensor, Tensor] | None = None
        if not module.system.known_physics:
            return Result()
        data = module.trainer.datamodule
        scores = {f"mse_{split}": self.one_step_mse(module, data.arrays[split]) for split in ("train", "test")}
        floor = module.model.true_counterpart(module.system)
        if floor is not None:
            floor = floor.double()
            scores.update(
                {
                    f"mse_{split}_floor": self.one_step_mse(module, data.arrays[split], floor)
                    for split in ("train", "test")
                }
            )
        scores.update(self.integration(module, data.substeps))
        return Result(scores)

    @staticmethod
    def one_step_mse(module: Learner, arrays: dict[str, Tensor], floor: DynamicsModel | None = None) -> float:
        """The one-step configuration MSE of the module's model on ``arrays`` (through ``module.predict``, in the
        model's dtype), or of ``floor``, a float64 ``true_counterpart`` of it, on the same windows by the same
        training integrator in float64."""
        model = module.model if floor is None else floor
        states, u, history, n = arrays["states"], arrays.get("u"), model.history, model.n
        windows = one_step_windows(states, history)
        inputs = None if u is None else one_step_windows(u, history)
        if floor is None:
            dtype = next(module.model.parameters()).dtype  # test states are float64, the model need not be
            batch = {"states": windows.to(module.device, dtype)}
            if inputs is not None:
                batch["u"] = inputs.to(module.device, dtype)
            pred = module.predict(batch)
        else:
            start = windows[:, 0] if history == 1 else windows[:, :history]
            times = module.times(windows.shape[1], windows.double())
            pred = rollout(floor, start.double(), times, module.integrator, None if inputs is None else inputs.double())
        return metrics.configuration_mse(
            pred[:, -1, :n].double().cpu(), windows[:, -1, :n].double(), q_angles(module)
        ).item()

    def integration(self, module: Learner, substeps: int) -> dict[str, float]:
        model, system = module.model, module.system
        t = torch.arange(self.steps + 1, dtype=torch.float64) * module.dt
        s0 = system.sample_initial(self.n_trajectories, torch.Generator().manual_seed(self.seed))
        true = system.to_chart(simulate(system, s0, t, substeps), system.base_chart, model.chart)
        start = true[:, 0] if model.history == 1 else true[:, : model.history]
        u = torch.zeros(self.n_trajectories, len(t), system.n_controls) if system.n_controls else None
        dtype = next(model.parameters()).dtype
        model.reset_diagnostics()
        pred = (
            rollout(
                model,
                start.to(module.device, dtype),
                t.to(module.device, dtype),
                module.integrator,
                None if u is None else u.to(module.device, dtype),
            )
            .double()
            .cpu()
        )
        n = model.n
        energy_pred, energy_true = system.energy(pred, model.chart), system.energy(true, model.chart)
        out = {
            "mse_integration": metrics.configuration_mse(pred[..., :n], true[..., :n], q_angles(module)).item(),
            "energy_mse_integration": metrics.energy_mse(energy_pred, energy_true[:, :1]).item(),
            **{f"{k}_integration": v for k, v in model.diagnostics().items()},
        }
        mass = getattr(model, "mass", None)
        if isinstance(mass, torch.nn.Module) and model.chart == system.base_chart:
            q = true[..., :n]
            learned = mass(q.to(module.device, dtype)).double().cpu()
            out["mass_mse"] = metrics.mass_matrix_mse(learned, system.mass_matrix(q)).item()
        self.drawn = t, pred, true, energy_pred, energy_true
        return out

    def figures(self, module: Learner) -> dict[str, Figure]:
        """``integration``: configuration and true energy along the first integration trajectory."""
        if self.drawn is None:
            return {}
        return figures.integration_figure(*self.drawn, chart=module.model.chart, title=module.run_title())


def q_angles(module: Learner) -> Tensor | None:
    """Which coordinates q of the model's chart are angles (compared on the circle), or None."""
    mask = module.system.angle_entries(module.model.chart)
    return None if mask is None else mask[: module.model.n]


def one_step_windows(values: Tensor, history: int) -> Tensor:
    """The windows of ``history`` + 1 steps of ``values`` (N, T, d) whose last step k is ≥ max(2, history),
    flattened over trajectories: (N · (T − max(2, history)), history + 1, d)."""
    first = max(0, 2 - history)  # window s predicts step s + history
    return values.unfold(1, history + 1, 1)[:, first:].movedim(-1, -2).flatten(0, 1)
