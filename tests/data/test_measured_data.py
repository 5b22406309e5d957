"""Measured data: one long recording with gaps and wrapped angles cut by time, the
acceleration objective's q̈ estimate, and the two trivial baselines every report shows."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import scipy.linalg
import torch

from encons.data.datamodule import TrajectoryDataModule
from encons.data.from_file import FileSystem
from encons.data.recording import load_recording, unwrap, wrap, write_example
from encons.infra.errors import ConfigError, DataError
from encons.numerics import metrics
from encons.systems.dissipative import DampedOscillator


def index_recording(path, n=60, dt=0.1, dropped=(17, 18, 40)):
    """A recording whose q is the sample's original index (q̇ = 0), with samples ``dropped``."""
    keep = np.setdiff1d(np.arange(n), dropped)
    states = np.stack([keep.astype(float), np.zeros(len(keep))], -1)
    np.savez(path, t=keep * dt, states=states)
    return path


def test_gaps_split_stretches_and_the_split_is_by_time(tmp_path):
    path = index_recording(tmp_path / "rec.npz")
    # span 0..5.9 s: train t < 0.7 * 5.9 = 4.13 (samples 0..41), val t < 0.8 * 5.9 = 4.72 (42..47), test 48..59.
    # Stretches: 0..16, 19..39, 41..59 (17, 18 and 40 dropped).
    t, splits, chart, inputs = load_recording(path, n_steps=4, test_steps=5, options={})
    first = {k: v[:, :, 0].long().tolist() for k, v in splits.items()}
    assert first["train"] == [
        [0, 1, 2, 3, 4],
        [4, 5, 6, 7, 8],
        [8, 9, 10, 11, 12],
        [12, 13, 14, 15, 16],
        [19, 20, 21, 22, 23],
        [23, 24, 25, 26, 27],
        [27, 28, 29, 30, 31],
        [31, 32, 33, 34, 35],
        [35, 36, 37, 38, 39],
    ]  # 41 alone: unused
    assert first["val"] == [[42, 43, 44, 45, 46]]  # 47: unused
    assert first["test"] == [[48, 49, 50, 51, 52, 53], [53, 54, 55, 56, 57, 58]]  # 59: unused
    torch.testing.assert_close(t, torch.arange(5, dtype=torch.float64) * 0.1)
    assert chart is None and inputs == {}


def test_a_recording_trains_through_the_data_module_in_windows_inside_stretches(tmp_path):
    path = index_recording(tmp_path / "rec.npz")
    data = TrajectoryDataModule(
        FileSystem(str(path)),
        "angle",
        path=str(path),
        n_steps=4,
        test_steps=5,
        chunk_len=3,
        noise=0.0,
        recording={"test_fraction": 0.2},
    )
    data.setup()
    for batch in data.train_dataloader():
        q = batch["states"][..., 0]
        torch.testing.assert_close(q.diff(dim=-1), torch.ones_like(q[:, 1:]))  # never across a gap
    assert data.states["test"].shape == (2, 6, 2) and data.dt == pytest.approx(0.1)


def test_recording_errors_are_one_line(tmp_path):
    path = index_recording(tmp_path / "rec.npz")
    with pytest.raises(ConfigError, match=r"data.recording.test_fractoin is not an option; allowed: test_fraction"):
        load_recording(path, 4, 5, {"test_fractoin": 0.3})
    with pytest.raises(
        DataError,
        match=r"test part holds no unbroken stretch of 31 samples \(its longest holds 12; .*\); allowed: "
        r".*data.test_steps",
    ):
        load_recording(path, 4, 30, {})
    np.savez(tmp_path / "odd.npz", t=np.array([0.0, 0.1, 0.2, 0.32, 0.42]), states=np.zeros((5, 2)))
    with pytest.raises(DataError, match=r"a step of 0.12 beside dt = 0.1"):
        load_recording(tmp_path / "odd.npz", 2, 2, {})


def test_wrapped_angles_round_trip(tmp_path):
    true = torch.stack(
        [torch.linspace(-3.0, 25.0, 400), torch.linspace(2.0, -2.0, 400), torch.full((400,), 70.0), torch.zeros(400)],
        -1,
    ).double()  # q₁ winds 4½ times
    wrapped = wrap(true, [True, False])
    assert bool((wrapped[:, 0] >= -math.pi).all() and (wrapped[:, 0] < math.pi).all())
    torch.testing.assert_close(unwrap(wrapped, [True, False]), true)  # true[0] lies in [−π, π)
    torch.testing.assert_close(wrap(unwrap(wrapped, [True, False]), [True, False]), wrapped)
    torch.testing.assert_close(unwrap(true, [True, False]), true)  # unwrapped input: unchanged
    np.savez(tmp_path / "rec.npz", t=np.arange(400) * 0.01, states=wrapped.numpy())
    _, splits, _, _ = load_recording(tmp_path / "rec.npz", 19, 19, {"angles": [True, False]})
    torch.testing.assert_close(splits["train"].flatten(0, 1), true[:280].unfold(0, 20, 19).movedim(-1, 1).flatten(0, 1))


def test_acceleration_from_a_recording_is_the_central_difference_of_q_dot(tmp_path):
    """The q̈ estimate on a known system: the damped oscillator recorded at h = 0.05 (the paper's)."""
    system = DampedOscillator()
    from encons.data.simulate import simulate

    t = torch.arange(2001, dtype=torch.float64) * 0.05
    states = simulate(system, torch.tensor([[1.0, 0.0]], dtype=torch.float64), t, substeps=2)[
        0
    ]  # RK4 at h/2: error ~1e-8
    np.savez(tmp_path / "osc.npz", t=t.numpy(), states=states.numpy())
    data = TrajectoryDataModule(
        FileSystem(str(tmp_path / "osc.npz")),
        "angle",
        path=str(tmp_path / "osc.npz"),
        n_steps=99,
        noise=0.0,
        objective="acceleration",
    )
    data.setup()
    train = data.arrays["train"]
    true = system.vector_field(train["states"].double(), "angle")[..., 1:]
    error = (train["rates"][..., 1:].double() - true).abs()
    assert error.max() < 1e-3  # h²/6 |d³q̇/dt³| inside, h²/3 at trajectory ends: ~4e-4 and ~8e-4
    assert error.mean() < 5e-4


def test_baselines_match_a_hand_computation_on_a_tiny_file(tmp_path, train_run):
    # q = t², q̇ = 2t: the linear ODE (q̇, q̈) = (q̇, 2) fits exactly, the constant predictor does not.
    t = np.arange(40) * 0.5
    np.savez(tmp_path / "tiny.npz", t=t, states=np.stack([t**2, 2 * t], -1))
    m = train_run(
        [
            "system=from_file",
            f"system.path={tmp_path / 'tiny.npz'}",
            "model=node",
            "data.n_steps=3",
            "data.test_steps=3",
            "data.chunk_len=3",
            "trainer.max_epochs=1",
            "horizon=3",
        ]
    )
    # test: t >= 0.8 * 19.5 = 15.6 -> samples 32..39 -> windows 32..35, 35..38; hand: mean of (s_k − s_0)², each
    # coordinate divided by its spread (standard deviation) over the test windows' samples.
    windows = [np.arange(32, 36), np.arange(35, 39)]
    sq, sv = np.std(np.concatenate([t[w] ** 2 for w in windows])), np.std(np.concatenate([2 * t[w] for w in windows]))
    hand = np.mean(
        [(((t[w] ** 2 - t[w[0]] ** 2) / sq) ** 2 + ((2 * t[w] - 2 * t[w[0]]) / sv) ** 2) / 2 for w in windows], 0
    )
    assert m["test/baseline_constant/state_mse"] == pytest.approx(hand.mean(), rel=1e-5)
    assert m["test/baseline_constant/state_mse_final"] == pytest.approx(hand[-1], rel=1e-5)
    assert m["test/baseline_linear_ode/state_mse"] < 1e-6 * hand.mean()
    assert "test/energy_mse" not in m and math.isfinite(m["test/state_mse"])


def test_linear_ode_baseline_is_numpys_least_squares_and_scipys_expm():
    gen = torch.Generator().manual_seed(0)
    train = torch.randn(3, 20, 4, generator=gen, dtype=torch.float64).cumsum(1)
    dt = 0.1
    rates = np.gradient(train.numpy(), dt, axis=1, edge_order=2)
    x = np.concatenate([train.numpy(), np.ones((3, 20, 1))], -1).reshape(-1, 5)
    coeffs = np.linalg.lstsq(x, rates.reshape(-1, 4), rcond=None)[0]  # (5, 4)
    start = torch.randn(2, 4, generator=gen, dtype=torch.float64)
    times = np.arange(6) * dt
    generator = np.vstack([coeffs.T, np.zeros((1, 5))])
    expected = np.stack(
        [[scipy.linalg.expm(generator * s) @ np.append(x0, 1.0) for s in times] for x0 in start.numpy()]
    )
    pred = metrics.linear_ode_rollout(metrics.fit_linear_ode(train, dt), start, torch.from_numpy(times))
    np.testing.assert_allclose(pred.numpy(), expected[..., :4], rtol=1e-9, atol=1e-9)
    assert metrics.constant_rollout(start, 6).shape == (2, 6, 4)


def test_unknown_system_skips_energy_with_a_note(tmp_path, train_run, caplog):
    path = write_example(tmp_path / "pendulum.npz", duration=12.0, dropped=((100, 2), (400, 1)))
    with caplog.at_level(logging.INFO, logger="encons"):
        m = train_run(
            [
                "system=from_file",
                f"system.path={path}",
                "model=second_order",
                "model.angular=true",
                "data.recording.angles=true",
                "data.n_steps=20",
                "data.test_steps=40",
            ]
        )
    assert "energy metrics skipped: system 'from_file' has no known energy" in caplog.text
    assert "MSE vs time" in caplog.text
    assert not any("energy" in k for k in m) and math.isfinite(m["test/baseline_linear_ode/state_mse"])


def test_readme_worked_example(tmp_path, train_run):
    """docs/data.md "Measured data": the example recording and the command given there, at a tiny budget."""
    import re
    from pathlib import Path

    readme = (Path(__file__).parents[2] / "docs" / "data.md").read_text()
    command = re.search(r"python -m encons.train (system=from_file system.path=example\.npz[^\n]*)", readme)
    assert command, "docs/data.md lost its worked example"
    write_example(tmp_path / "example.npz")
    args = [a.replace("example.npz", str(tmp_path / "example.npz")) for a in command.group(1).replace("\\", "").split()]
    m = train_run([*args, "trainer.max_epochs=1", "model.hidden=16"])
    assert math.isfinite(m["test/state_mse_final"]) and "test/baseline_constant/state_mse_final" in m


@pytest.mark.parametrize("model", ["glnn", "second_order"])
def test_acceleration_objective_trains(train_run, model):
    m = train_run([f"model={model}", "system=damped_oscillator", "objective=acceleration"])
    assert math.isfinite(m["test/state_mse"]) and math.isfinite(m["test/energy_mse_final"])
    assert m["test/baseline_linear_ode/state_mse"] < 1e-3  # the damped oscillator is a linear ODE
