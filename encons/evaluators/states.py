"""Scores of rollouts in state space, beside the oracle row and two trivial baselines."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, cast

import torch
from matplotlib.figure import Figure
from torch import Tensor

from encons.evaluators import figures
from encons.evaluators.base import Evaluator, Result, TestBatch, gathered
from encons.infra.errors import ConfigError
from encons.numerics import metrics

if TYPE_CHECKING:
    from encons.numerics.learner import Learner

log = logging.getLogger(__name__)


class States(Evaluator):
    """Test rollouts scored in the system's common chart (``encons.numerics.metrics.summarise``: trajectory relative
    error over the ``horizon`` and, as ``traj_rel_err_window``, over the whole test window, final relative
    error, Finzi's geometric mean, valid prediction time, energy errors where the physics is known, the
    divergence fraction; ``windows``, the number of test windows those are means over), the constant and
    linear-ODE baselines scored by the same metrics (``baseline_<name>/...``), the long-rollout MSE against
    time of all three (``metrics.long_rollout_errors``), the model's solver counters, and, on a system of known
    physics, ``oracle/<metric>``: the true field rolled out by the same evaluation from the same starts in
    the model's chart and scored by the same metrics. Runs whose observations are the states only."""

    headline = (  # the benchmark summary's headline columns (encons.tools.report)
        "diverged",
        "traj_rel_err",
        "geom_rel_err",
        "vpt",
        "energy_abs_err",
        "energy_rmse_median",
        "state_mse",
        "state_mse_final",
        "energy_mse",
        "energy_mse_final",
        "baseline_constant/state_mse_final",
        "baseline_linear_ode/state_mse_final",
    )

    def check(self, module: Learner) -> None:
        if not module.observation.identity:
            raise ConfigError(
                f"evaluators.states does not apply to observation={type(module.observation).__name__} "
                f"(the model's states are not the data's); allowed: evaluators=[pixels]"
            )

    def reset(self) -> None:
        self.batches: list[tuple[Tensor, ...]] = []
        self.diagnostics: dict[str, float] = {}

    def update(self, module: Learner, batch: TestBatch) -> None:
        x, pred = batch.x, batch.pred
        kept: tuple[Tensor, ...] = (x, pred)
        if module.system.known_physics:  # the floor: the true field, same starts and integrator
            kept += (
                module.evaluation.oracle(
                    module.system, module.model.chart, x[:, 0], module.times(x.shape[1], x), batch.batch.get("u")
                ),
            )
        self.batches.append(tuple(p.detach() for p in kept))
        self.diagnostics = module.model.diagnostics()  # counters since the test began: the last is the total

    def compute(self, module: Learner) -> Result:
        true, pred, *oracle = (p.double() for p in gathered(module, self.batches))
        self.batches.clear()
        system, chart = module.system, module.model.chart
        energy = (lambda s: system.energy(s, chart)) if system.known_physics else None
        if energy is None:
            log.info("energy metrics skipped: system '%s' has no known energy", system.name)
        energies = [energy(s) for s in (pred, true)] if energy else None
        true_c, pred_c = module.to_common(true), module.to_common(pred)
        angles = module.compared_angles
        score: dict[str, Any] = dict(
            horizon=module.horizon, dt=module.dt, vpt_threshold=module.evaluation.vpt_threshold, angles=angles
        )
        scores = metrics.summarise(pred_c, true_c, *(energies or (None, None)), **score)
        scores["windows"] = float(len(true))
        train = module.trainer.datamodule.states["train"].to(true)
        baselines = metrics.baseline_rollouts(true, train, module.dt)
        for name, rollout in baselines.items():  # every metric the model gets, on the same windows
            scored = metrics.summarise(
                module.to_common(rollout),
                true_c,
                energy(rollout) if energy else None,
                energies[1] if energies else None,
                **score,
            )
            scores.update({f"{name}/{k}": v for k, v in scored.items()})
        families = metrics.unit_families(system.units(system.common_chart))
        scalars, curves = metrics.long_rollout_errors(true, pred, baselines, module.to_common, energy, angles, families)
        scores.update(scalars)
        scores.update(self.diagnostics)  # e.g. SyMo's non-converged root-finds
        if oracle:  # the floor, scored by the same metrics
            floor = metrics.summarise(
                module.to_common(oracle[0]),
                true_c,
                energy(oracle[0]) if energy else None,
                energies[1] if energies else None,
                **score,
            )
            scores.update({f"oracle/{k}": v for k, v in floor.items()})
        t = module.times(true.shape[1], true)
        log.info("%s", metrics.curves_table(t, curves))
        kept = {
            "t": t.cpu().numpy(),
            "rel_err": metrics.relative_error(pred_c, true_c, angles).cpu().numpy(),
            **{f"{k}_{name}": v.cpu().numpy() for name, c in curves.items() for k, v in c.items()},
        }
        if energies:
            kept["energy_err"] = metrics.energy_abs_error(*energies).cpu().numpy()
        self.drawn = t, pred_c, true_c, energies, curves, module.to_common(baselines["baseline_linear_ode"])
        return Result(scores, kept)

    def figures(self, module: Learner) -> dict[str, Figure]:
        """``mse_vs_time`` (model and baselines), ``rollout`` (with the linear-ODE baseline's rollout),
        ``relative_error`` and ``energy_error`` (``encons.evaluators.figures``)."""
        t, pred_c, true_c, energies, curves, baseline = self.drawn  # the linear-ODE rollout compute scored
        units, title = module.system.units(module.system.common_chart), module.run_title()
        time_label = figures.TIME if module.system.known_physics else figures.DATA_TIME
        names = figures.coordinate_names(
            true_c.shape[-1], module.system.layout if module.system.common_chart == "cartesian" else None
        )
        return {
            **figures.mse_figure(t.cpu(), curves, title=title, units=units, time_label=time_label),
            **figures.rollout_figures(
                t.cpu(),
                pred_c.cpu(),
                true_c.cpu(),
                [e.cpu() for e in energies] if energies else None,
                title=title,
                units=units,
                baseline=baseline.cpu(),
                angles=module.compared_angles,
                names=names,
                time_label=time_label,
                chart=module.system.common_chart,
            ),
        }

    def ensemble_figures(self, module: Learner, members: list[Evaluator], seeds: list[int]) -> dict[str, Figure]:
        """``ensemble_rollout`` and ``ensemble_relative_error`` (``encons.plots.ensemble_figures``) of the members'
        test rollouts (the same windows for every member)."""
        t, _, true_c, *_ = self.drawn
        preds = torch.stack([cast(States, m).drawn[1] for m in members]).cpu()  # members' evaluators of this name
        names = figures.coordinate_names(
            true_c.shape[-1], module.system.layout if module.system.common_chart == "cartesian" else None
        )
        return figures.ensemble_figures(
            t.cpu(),
            preds,
            true_c.cpu(),
            module.run_title(),
            seeds,
            units=module.system.units(module.system.common_chart),
            angles=module.compared_angles,
            names=names,
            time_label=figures.TIME if module.system.known_physics else figures.DATA_TIME,
        )
