"""The evaluation measures the model, not the harness (``encons.numerics.evaluation``): its default integrator
puts the true field's own error far below the errors it ranks, and models are scored beside that floor."""

from __future__ import annotations

import pytest
import torch

from encons.config.check import validate
from encons.data.simulate import sample_trajectories
from encons.entry import api
from encons.models.base import TrueField
from encons.numerics import metrics
from encons.numerics.evaluation import Evaluation
from encons.numerics.integrators import Integrator, rollout
from encons.training.build import build_system
from tests.helpers import simulated_systems

#: Systems scored on states (a pixel system is scored on frames: no state oracle).
STATE_SYSTEMS = [
    s for s in simulated_systems() if api.compose(f"system={s}", output_dir=".").system.get("frame_size") is None
]
#: Steps of the test horizon checked here: Lim & Kasim's and Xiao et al.'s horizons of 462–4759 steps cost
#: minutes of ground-truth simulation and dopri5 each; the whole horizons are measured by
#: ``benchmarks/evaluation_floor.py --long`` (benchmarks/reports/evaluation-floor/), where Lim & Kasim's chaotic
#: double pendulum parts from the data (5e-3 over 100 s).
STEPS = 30


def simulated_test_set(name: str, n: int = 8, steps: int | None = STEPS):
    """``n`` test trajectories of ``name`` simulated as its data config does, over its test horizon (at most
    ``steps`` steps)."""
    cfg = api.compose(f"system={name}", output_dir=".")
    system = build_system(validate(cfg))
    horizon = cfg.data.test_steps or cfg.data.n_steps
    t = torch.arange(min(horizon, steps or horizon) + 1, dtype=torch.float64) * cfg.data.dt
    true, u, _ = sample_trajectories(system, n, t, torch.Generator().manual_seed(5), cfg.data.substeps)
    return system, t, true, u


def floor(system, chart, t, true, u, evaluation: Evaluation) -> float:
    """geom_rel_err of the true field in ``chart`` rolled out by ``evaluation``, in the common chart."""
    start = system.to_chart(true[:, 0], system.base_chart, chart)
    pred = evaluation.oracle(system, chart, start, t, None if u is None else u)
    common = system.to_chart(pred, chart, system.common_chart)
    return (
        metrics.geometric_mean_relative_error(common, system.to_chart(true, system.base_chart, system.common_chart))
        .mean()
        .item()
    )


@pytest.mark.parametrize("name", STATE_SYSTEMS)
def test_true_field_scores_below_1e_6_under_the_default_evaluation(name):
    system, t, true, u = simulated_test_set(name)
    for chart in system.charts:
        assert floor(system, chart, t, true, u, Evaluation()) <= 1e-6, chart


def test_the_training_integrator_alone_would_not():
    """RK4 at the data dt (what test rollouts used before) scores the gyroscope's true field above
    1e-5 in the Cartesian chart: the bound above is not met by any integrator."""
    system, t, true, u = simulated_test_set("gyroscope")
    assert floor(system, "cartesian", t, true, u, Evaluation(method="rk4", substeps=1)) > 1e-5


def test_float64_rollout_leaves_the_model_alone():
    system, t, true, _ = simulated_test_set("pendulum1", n=2)
    model = TrueField(system, "angle")
    model.register_parameter("w", torch.nn.Parameter(torch.ones(1)))
    pred = Evaluation().rollout(model, true[:, 0].float(), t)
    assert pred.dtype == torch.float64 and model.w.dtype == torch.float32
    assert torch.equal(
        pred,
        rollout(
            TrueField(system, "angle"), true[:, 0].float().double(), t, Integrator("dopri5", rtol=1e-10, atol=1e-12)
        ),
    )


def test_where_the_adaptive_solver_gives_up_rk4_takes_over():
    """Past ``max_steps`` per dt dopri5 stops and the rollout is RK4 x16's (bounded cost); a field that
    turns NaN makes the step underflow, and its RK4 rollout is NaN: diverged, not an exception."""

    class Broken(TrueField):
        def forward(self, t, s, u=None):
            return super().forward(t, s, u) * torch.where(t > 0.5, float("nan"), 1.0)

    system, t, true, _ = simulated_test_set("pendulum1", n=2)
    stubborn = Evaluation(max_steps=1, rtol=1e-13, atol=1e-15).oracle(system, "angle", true[:, 0], t)
    assert torch.equal(stubborn, rollout(TrueField(system, "angle"), true[:, 0], t, Integrator("rk4", 16)))
    pred = Evaluation().rollout(Broken(system, "angle"), true[:, 0], t)
    assert pred.shape == true.shape and pred[:, -1].isnan().all() and pred[:, 1].isfinite().all()
    assert metrics.summarise(pred, true, None, None)["diverged"] == 1.0


def test_valid_prediction_time_by_hand():
    """Relative errors 0, 0.05, 0.2, 0.05 (threshold 0.1): valid up to t_1 = dt even though the error
    drops again; a trajectory that never exceeds scores the horizon t_3; a NaN ends it."""
    true = torch.ones(3, 4, 1, dtype=torch.float64)
    pred = true.clone()
    pred[0, :, 0] += torch.tensor([0.0, 0.05, 0.2, 0.05], dtype=torch.float64)
    pred[1, :, 0] += 0.09
    pred[2, 2, 0] = float("nan")
    vpt = metrics.valid_prediction_time(pred, true, dt=0.5, threshold=0.1)
    assert vpt.tolist() == [0.5, 1.5, 0.5]
    summary = metrics.summarise(pred, true, None, None, dt=0.5, vpt_threshold=0.1)
    assert summary["vpt"] == pytest.approx(2.5 / 3) and summary["vpt_censored"] == pytest.approx(1 / 3)
