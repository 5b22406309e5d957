"""The papers' metrics against hand computations on tiny trajectories."""

from __future__ import annotations

import math

import torch
from encons import metrics


def test_relative_and_trajectory_error_by_hand():
    true = torch.ones(1, 6, 2)  # ‖s_t‖ = √2
    pred = true.clone()
    pred[0, 1:, 0] += 0.1       # ‖ŝ_t − s_t‖ = 0.1 from t = 1
    rel = metrics.relative_error(pred, true)
    assert torch.allclose(rel[0, 1:], torch.full((5,), 0.1 / math.sqrt(2)))
    # Zhong et al.: sum over t = 0..4 (five steps, the first exact)
    assert math.isclose(metrics.trajectory_relative_error(pred, true, 4).item(), 4 * 0.1 / math.sqrt(2), rel_tol=1e-6)


def test_geometric_mean_skips_t0_and_matches_by_hand():
    true = torch.ones(1, 3, 1)
    pred = torch.tensor([[[1.0], [2.0], [4.0]]])
    e1, e2 = 1 / 3, 3 / 5  # |ŝ−s| / (|ŝ| + |s|) at t = 1, 2
    assert math.isclose(metrics.geometric_mean_relative_error(pred, true).item(), math.sqrt(e1 * e2), rel_tol=1e-6)


def test_summary_counts_diverged_rollouts_and_keeps_nan():
    true = torch.ones(4, 10, 2)
    pred = true.clone()
    pred[1, 7:] = float("nan")  # one rollout blows up after the T = 4 horizon
    out = metrics.summarise(pred, true, None, None, horizon=4)
    assert out["diverged"] == 0.25
    assert out["traj_rel_err"] == 0.0          # the horizon cannot see it ...
    assert math.isnan(out["rel_err_final"])    # ... the long-horizon metrics do, and stay NaN


def test_a_finite_rollout_whose_energy_error_explodes_counts_as_diverged():
    """Lim & Kasim's double pendulum: states finite, energy RMSE 1e7–1e10 — not 'diverged 0'."""
    true = torch.ones(4, 10, 2)
    pred = true.clone()
    true_e = torch.ones(4, 10)
    pred_e = true_e.clone()
    pred_e[0, 5] = 1e10 + 1.0     # reaches the bound
    pred_e[1, 9] = float("inf")  # non-finite energy of finite states
    pred_e[2, 3] = 1e9           # large but below the bound: still a (bad) prediction
    out = metrics.summarise(pred, true, pred_e, true_e, horizon=4)
    assert out["diverged"] == 0.5
    assert metrics.diverged(pred, pred_e, true_e).tolist() == [True, True, False, False]


def test_energy_rmse_against_the_true_energy_at_each_time():
    true_e = torch.tensor([[1.0, 0.5, 0.25]])
    pred_e = torch.tensor([[1.0, 0.5, 0.0]])
    assert math.isclose(metrics.energy_deviation_rmse(pred_e, true_e).item(), math.sqrt(0.25 ** 2 / 3), rel_tol=1e-6)
