"""Test-time evaluation, apart from training: its own integrator, and the oracle that shows its floor.

Test, ``evaluate`` and benchmark rollouts of continuous models integrate with ``Evaluation`` (config
node ``evaluation``), in float64 by default; training and validation keep the ``integrator`` group,
and discrete models (SyMo) advance by their own step in both. The oracle is the system's true field
in the model's chart (``TrueField``), rolled out by the same ``rollout`` from the same starts and
scored by the same metrics: the error the evaluation itself contributes, beside every model.

Default: Dormand–Prince 5(4) (torchdiffeq ``dopri5``) at rtol 1e-10, atol 1e-12 in float64, chosen
by measurement (docs/metrics.md): the true field then scores geom_rel_err ≤ 3.1e-7 against the
simulated test trajectories of every non-chaotic system of ``conf/system`` over its test horizon (the
data's own RK4 error is most of it; Lim & Kasim's double pendulum is chaotic over its 100 s horizon, so
its floor is that error amplified, 5e-3: benchmarks/reports/evaluation-floor), where RK4 at the data dt (the training
integrator) scored up to 1.1e-4 (gyroscope, Cartesian) — above the published errors it was compared with — and even 16
RK4 steps per dt scored 3.7e-5 (Lim & Kasim's pendulum, Cartesian, 462 steps). An adaptive method also adapts to the
learned field it integrates; the true fields took 2–20 dopri5 steps per data dt (46–121 evaluations). Limits: one step
size for the whole batch; a rollout that needs more than ``max_steps`` (100) steps per data dt, or whose step underflows
(e.g. at NaN), is rolled out again by RK4 with 16 steps per dt (bounded cost; a warning says so), so a learned field
much stiffer than the truth is scored on that coarser rollout; the floor of a chaotic system grows with the horizon.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass

import torch
from torch import Tensor

from encons.infra import bounds
from encons.infra.bounds import Count, Positive
from encons.models.base import DynamicsModel, TrueField
from encons.numerics.integrators import FIXED_STEP, Integrator, rollout
from encons.systems.base import System

log = logging.getLogger(__name__)
FALLBACK = Integrator("rk4", 16)  # where an adaptive rollout gives up: bounded cost, 64 evaluations per dt


@dataclass(frozen=True)
class Evaluation:
    """How test rollouts integrate: a torchdiffeq ``method`` (fixed-step: ``substeps`` per data dt;
    adaptive: ``rtol``, ``atol``, at most ``max_steps`` per data dt, then ``FALLBACK``), in float64 when ``float64``;
    ``vpt_threshold`` is the relative error that ends the valid prediction time
    (``encons.numerics.metrics.valid_prediction_time``); ``source`` names a paper whose test integration a profile
    reproduces (printed with the metrics)."""

    method: str = "dopri5"
    substeps: Count = 1
    rtol: Positive = 1e-10
    atol: Positive = 1e-12
    max_steps: Count = 100
    float64: bool = True
    vpt_threshold: Positive = 0.1
    source: str = ""

    def __post_init__(self) -> None:
        bounds.check(vars(self), bounds.hints(Evaluation), "evaluation", types=False)
        self.integrator  # noqa: B018 - validates method

    @property
    def integrator(self) -> Integrator:
        return Integrator(self.method, self.substeps, self.rtol, self.atol, self.max_steps)

    def describe(self) -> str:
        """One line: the method, its step or tolerances, the precision and the paper it follows."""
        step = (
            f"{self.substeps} steps per data dt"
            if self.method in FIXED_STEP
            else f"rtol {self.rtol:g}, atol {self.atol:g}"
        )
        return f"evaluation: {self.method}, {step}, {'float64' if self.float64 else 'model dtype'}" + (
            f" ({self.source})" if self.source else ""
        )

    def precise(self, model: DynamicsModel) -> DynamicsModel:
        """``model`` as this evaluation computes with it: with ``float64``, a float64 copy where any parameter
        is not float64 already (the model itself is left as it is); else ``model``."""
        if self.float64 and any(p.dtype != torch.float64 for p in model.parameters()):
            return copy.deepcopy(model).double()
        return model

    def rollout(self, model: DynamicsModel, start: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """``encons.numerics.integrators.rollout`` of ``model`` with this integrator; with ``float64`` on a float64
        copy of the model (the model itself is left as it is), else in the model's dtype."""
        original, model = model, self.precise(model)
        start = start.double() if self.float64 else start.to(next(model.parameters(), start))
        try:
            return rollout(model, start, t, self.integrator, u)
        except AssertionError as err:  # torchdiffeq's adaptive step control gave up on the model's field
            if model.discrete or not str(err).startswith(("max_num_steps exceeded", "underflow in dt")):
                raise
            log.warning(
                "evaluation: %s not integrable by %s at rtol %g within %d steps per dt (%s): rolled out "
                "by rk4 with %d steps per dt instead",
                type(model).__name__,
                self.method,
                self.rtol,
                self.max_steps,
                err,
                FALLBACK.substeps,
            )
            return rollout(model, start, t, FALLBACK, u)
        finally:
            if model is not original:  # the copy's solver counters (e.g. SyMo's Newton failures) are the model's
                original.sync_diagnostics(model)

    def oracle(self, system: System, chart: str, start: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """The true field's rollout in ``chart`` from continuous-model starts ``start`` (..., 2n): the floor."""
        return self.rollout(TrueField(system, chart), start, t, u)
