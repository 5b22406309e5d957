"""The papers' metrics against hand computations on tiny trajectories."""

from __future__ import annotations

import math

import torch

from encons.numerics import metrics


def test_relative_and_trajectory_error_by_hand():
    true = torch.ones(1, 6, 2)  # ‖s_t‖ = √2
    pred = true.clone()
    pred[0, 1:, 0] += 0.1  # ‖ŝ_t − s_t‖ = 0.1 from t = 1
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
    assert out["traj_rel_err"] == 0.0  # the horizon cannot see it ...
    assert math.isnan(out["rel_err_final"])  # ... the long-horizon metrics do, and stay NaN


def test_a_finite_rollout_whose_energy_error_explodes_counts_as_diverged():
    """Lim & Kasim's double pendulum: states finite, energy RMSE 1e7–1e10 — not 'diverged 0'."""
    true = torch.ones(4, 10, 2)
    pred = true.clone()
    true_e = torch.ones(4, 10)
    pred_e = true_e.clone()
    pred_e[0, 5] = 1e10 + 1.0  # reaches the bound
    pred_e[1, 9] = float("inf")  # non-finite energy of finite states
    pred_e[2, 3] = 1e9  # large but below the bound: still a (bad) prediction
    out = metrics.summarise(pred, true, pred_e, true_e, horizon=4)
    assert out["diverged"] == 0.5
    assert metrics.diverged(pred, pred_e, true_e).tolist() == [True, True, False, False]


def test_energy_rmse_against_the_true_energy_at_each_time():
    true_e = torch.tensor([[1.0, 0.5, 0.25]])
    pred_e = torch.tensor([[1.0, 0.5, 0.0]])
    assert math.isclose(metrics.energy_deviation_rmse(pred_e, true_e).item(), math.sqrt(0.25**2 / 3), rel_tol=1e-6)


def _state_metrics():
    """Every function of ``encons.numerics.metrics`` that scores predicted states against true ones (pred…, true…)."""
    import inspect

    found = {}
    for name, fn in inspect.getmembers(metrics, inspect.isfunction):
        params = list(inspect.signature(fn).parameters)
        if (
            fn.__module__ == metrics.__name__
            and len(params) >= 2
            and params[0].startswith("pred")
            and params[1].startswith("true")
            and not any(w in params[0] for w in ("energy", "mass", "rates"))
        ):
            found[name] = fn
    return found


def test_every_state_metric_is_unchanged_when_an_angle_of_prediction_and_truth_shifts_by_2pi_k():
    found = _state_metrics()
    assert {
        "relative_error",
        "trajectory_relative_error",
        "geometric_mean_relative_error",
        "valid_prediction_time",
        "summarise",
        "mse_curves",
        "configuration_mse",
    } <= set(found)
    gen = torch.Generator().manual_seed(0)
    true = torch.randn(5, 12, 4, generator=gen, dtype=torch.float64)
    true[..., 0] = true[..., 0] * 2 + 2.5  # an angle reaching past π
    pred = true + 0.3 * torch.randn(true.shape, generator=gen, dtype=torch.float64)
    pred[0, 6, 0] = true[0, 6, 0] + 2 * math.pi - 0.1  # one prediction one turn off: 0.1 on the circle
    angles = torch.tensor([True, False, False, False])
    extra = {"valid_prediction_time": (0.1, 0.5), "summarise": (None, None)}
    for k in (1, -3, 7):
        turn = torch.zeros(4, dtype=torch.float64)
        turn[0] = 2 * math.pi * k
        for name, fn in found.items():
            args = extra.get(name, ())
            base, moved = fn(pred, true, *args, angles=angles), fn(pred + turn, true + turn, *args, angles=angles)
            for a, b in zip(*(v.values() if isinstance(v, dict) else [v] for v in (base, moved))):
                torch.testing.assert_close(
                    torch.as_tensor(b),
                    torch.as_tensor(a),
                    rtol=1e-9,
                    atol=1e-12,
                    msg=f"{name} moved under a 2π·{k} shift",
                )
    # the error of an angle is the wrapped difference: 0.1, not 2π − 0.1
    rel = metrics.relative_error(pred[:1, 6:7], true[:1, 6:7], angles)
    d = (pred[0, 6] - true[0, 6]).clone()
    d[0] = -0.1
    s = true[0, 6].clone()
    s[0] = torch.remainder(s[0] + math.pi, 2 * math.pi) - math.pi
    assert math.isclose(rel.item(), (d.norm() / s.norm()).item(), rel_tol=1e-12)
    # without angles the plain definitions hold (and a shift moves them: the test above can fail)
    assert (
        metrics.relative_error(pred + 2 * math.pi, true + 2 * math.pi).mean()
        < metrics.relative_error(pred, true).mean()
    )
