"""Issue 51, item 1: an honest headline on recordings — the whole test window first, with the number of test
windows; the baselines scored by every metric the model is; a state MSE in consistent units; trial labels as
written by a person."""

import logging
import math

import numpy as np
import pytest
import torch

from encons.numerics import metrics
from encons.training.summary import headline, print_summary


def _pendulum_text(path, trial: str = "0.0000000000000000e+000"):
    """A damped pendulum sampled at 1/6 s with dropped samples, as a MATLAB-style text file with a trial column."""
    from scipy.integrate import solve_ivp

    t = np.arange(0, 40, 1 / 6)
    y = solve_ivp(
        lambda _, s: [s[1], -9.81 * np.sin(s[0]) - 0.05 * s[1]], (0, t[-1]), [2.0, 0.0], t_eval=t, rtol=1e-9, atol=1e-9
    ).y
    keep = np.ones(len(t), bool)
    keep[[31, 77, 140]] = False
    rows = [f"{a:.6f} {b:.9f} {c:.9f} {trial}" for a, b, c in zip(t[keep], *y[:, keep])]
    path.write_text("% time theta omega trial\n" + "\n".join(rows) + "\n")
    return path


def test_state_mse_divides_each_coordinate_by_its_spread_and_keeps_the_raw_mean():
    true = torch.zeros(4, 6, 2, dtype=torch.float64)
    true[..., 0] = torch.linspace(-1, 1, 6)  # rad: spread s
    true[..., 1] = torch.linspace(-10, 10, 6)  # rad/s: ten times that
    pred = true.clone()
    pred[..., 0] += 0.1
    pred[..., 1] += 1.0  # the same error relative to each spread
    curves = metrics.mse_curves(pred, true)
    spread = metrics.coordinate_spread(true)
    assert torch.allclose(spread[1], 10 * spread[0])
    assert torch.allclose(curves["state_mse_raw"], torch.full((6,), (0.01 + 1.0) / 2, dtype=torch.float64))
    expected = (0.1 / spread[0]) ** 2  # both coordinates add the same dimensionless share
    assert torch.allclose(curves["state_mse"], expected.expand(6))


def test_an_angle_spread_is_taken_on_the_circle():
    true = torch.tensor([[[math.pi - 0.1, 0.0], [-math.pi + 0.1, 0.0]]], dtype=torch.float64)
    spread = metrics.coordinate_spread(true, torch.tensor([True, False]))
    assert spread[0].item() == pytest.approx(0.1, rel=1e-9) and spread[1].item() == 1.0  # not ~π; still: 1


def test_headline_flags_a_horizon_that_ranks_otherwise_and_too_few_windows():
    results = {
        "test/windows": 2.0,
        "test/traj_rel_err": 0.43,
        "test/traj_rel_err_window": 9.2,
        "test/state_mse": 0.11,
        "test/baseline_linear_ode/traj_rel_err": 0.40,
        "test/baseline_linear_ode/traj_rel_err_window": 19.3,
        "test/baseline_linear_ode/state_mse": 0.51,
        "test/baseline_constant/traj_rel_err": 3.0,
        "test/baseline_constant/traj_rel_err_window": 28.9,
        "test/baseline_constant/state_mse": 2.0,
    }
    lines = headline(results)
    assert lines[0].startswith("whole test window, mean of 2 test window(s): traj_rel_err_window model 9.2, ")
    assert "state_mse (per coordinate / its test-set spread) model 0.11" in lines[0]
    assert "traj_rel_err baseline_linear_ode < model < baseline_constant" in lines[1]
    assert "whole window model < baseline_linear_ode < baseline_constant" in lines[1]
    assert "2 test window(s) give these scores no spread" in lines[2]
    many = {**results, "test/windows": 40.0, "test/baseline_linear_ode/traj_rel_err": 0.5}
    assert len(headline(many)) == 1  # same order, enough windows: the score line alone


def test_summary_opens_with_the_headline_and_counts_vpt_windows(tmp_path, capsys):
    print_summary(
        "node on from_file",
        {"test/windows": 3.0, "test/vpt": 0.25, "test/traj_rel_err": 1.0, "test/traj_rel_err_window": 5.0},
        tmp_path,
    )
    out = capsys.readouterr().out
    assert out.startswith("whole test window, mean of 3 test window(s)")
    assert "0.25 (mean of 3 windows)" in out


def test_a_recording_run_scores_the_baselines_like_the_model(tmp_path, train_run, caplog):
    path = _pendulum_text(tmp_path / "lab.txt")
    with caplog.at_level(logging.INFO, logger="encons"):
        m = train_run(
            [
                "system=from_file",
                f"system.path={path}",
                "model=node",
                "data.recording.comment='%'",
                "data.recording.columns={t: time, q: [theta], qdot: [omega], trial: trial}",
                "data.recording.angles=true",
                "data.n_steps=12",
                "trainer.max_epochs=1",
            ]
        )
    assert "trial 0: t 0.." in caplog.text and "e+000" not in caplog.text
    assert m["test/windows"] >= 1
    for baseline in ("baseline_constant", "baseline_linear_ode"):
        for metric in ("vpt", "geom_rel_err", "traj_rel_err", "traj_rel_err_window", "state_mse", "diverged"):
            assert math.isfinite(m[f"test/{baseline}/{metric}"]), (baseline, metric)
    assert math.isfinite(m["test/state_mse_raw"]) and m["test/state_mse"] != m["test/state_mse_raw"]
