"""The one-step acceleration error on held-out states: the test error of Xiao et al.'s Tables 3–4."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from encons.evaluators.base import Evaluator, Result
from encons.infra.errors import ConfigError
from encons.numerics import metrics
from encons.numerics.integrators import state_derivative

if TYPE_CHECKING:
    from encons.numerics.learner import Learner

log = logging.getLogger(__name__)


class Acceleration(Evaluator):
    """``accel_mse``: Xiao et al.'s loss (§3, (1/|S|) Σ ‖q̈̃ − q̈‖², ``encons.numerics.metrics.acceleration_mse``) at
    held-out states — the model's field against the system's true field at each state of the test
    trajectories' first ``data.n_steps`` + 1 steps (the time span a training trajectory covers), no
    rollout. The paper tests on a random half of its (x_t, x_{t+1}) pairs and prints that test error,
    unnamed, in Tables 3–4 (§4.4); here the held-out states are whole test trajectories from the same
    initial-state range (as many points as the paper's test half on both of its systems). Computed as
    the run's ``evaluation`` computes (float64 by default). Limits: a system of known physics, observed in
    its states; q̈ is the second half of the state in the model's chart; a discrete model (no field) scores
    nothing; the points are the test states, clean (no noise)."""

    headline = ("accel_mse",)  # the benchmark summary's headline column (encons.tools.report)

    def check(self, module: Learner) -> None:
        if not module.observation.identity or not module.system.known_physics:
            why = "its states are not the data's" if not module.observation.identity else "it has no true field"
            raise ConfigError(
                f"evaluators.acceleration does not apply to system {module.system.name} ({why}); "
                f"allowed: a system of known physics observed in its states, or ~evaluators/acceleration"
            )

    def compute(self, module: Learner) -> Result:
        if module.model.discrete:  # no field to score; its system may still choose this evaluator
            log.info("accel_mse skipped: %s is a discrete model (no field)", type(module.model).__name__)
            return Result()
        data = module.trainer.datamodule
        arrays = data.arrays["test"]
        span = data.n_steps + 1
        states, u = arrays["states"][:, :span], arrays.get("u")
        u = None if u is None else u[:, :span]
        model = module.evaluation.precise(module.model)
        dtype = next(model.parameters(), states).dtype
        states = states.to(module.device, dtype)
        u = None if u is None else u.to(module.device, dtype)
        pred = state_derivative(model, states, u).detach()
        true = module.system.field(states.double(), model.chart, None if u is None else u.double())
        return Result({"accel_mse": metrics.acceleration_mse(pred.double(), true).item()})
