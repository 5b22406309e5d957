"""GLNN (Xiao, Zhang & Tang 2024, eq. (11)) and the dissipative systems it is benchmarked on.

Closed forms: GLNN fed the true L and F gives the true q̈; with F ≡ 0 it is LNN; the damped
oscillator's simulated energy follows the closed-form solution and decays monotonically.
"""

from __future__ import annotations

import math
from functools import partial

import pytest
import torch

from encons.data.simulate import simulate
from encons.models.glnn import GLNN, SecondOrder
from encons.models.lnn import LNN, lagrangian_derivatives
from encons.systems.dissipative import CompoundPendulum, DampedOscillator
from encons.systems.pendulum import NPendulum

SYSTEMS = {"damped_oscillator": DampedOscillator, "compound_pendulum": CompoundPendulum}


def states(system, n=64, seed=3):
    return 2 * system.sample_initial(n, torch.Generator().manual_seed(seed))  # beyond the sampled box too


@pytest.mark.parametrize("angular", [False, True])
@pytest.mark.parametrize("name", SYSTEMS)
def test_glnn_with_true_lagrangian_and_force_gives_true_acceleration(name, angular):
    system = SYSTEMS[name]()
    model = GLNN(system, hidden=8, depth=2, guard=0.0, angular=angular).double()
    model.lagrangian_derivatives = partial(lagrangian_derivatives, system.lagrangian)  # torch.func, of any L
    model.force = system.force
    s = states(system)
    field = model(torch.zeros(()), s)
    torch.testing.assert_close(field, system.vector_field(s, "angle"), rtol=0, atol=1e-10)
    assert field.shape == s.shape and bool(system.force(s).abs().max() > 1e-2)  # the force matters


def test_glnn_without_force_is_lnn_on_a_conservative_system():
    system = NPendulum(2, masses=[1.0, 1.5], lengths=[1.0, 0.8])
    s = system.sample_initial(64, torch.Generator().manual_seed(4))
    t = torch.zeros(())
    glnn, lnn = (
        GLNN(system, hidden=16, depth=2, guard=0.0).double(),
        LNN(system, hidden=16, depth=2, guard=0.0).double(),
    )
    glnn.lagrangian_derivatives = lnn.lagrangian_derivatives = partial(
        lagrangian_derivatives, _pendulum_lagrangian(system)
    )
    glnn.force = lambda x: torch.zeros_like(x[..., :2])
    torch.testing.assert_close(glnn(t, s), lnn(t, s), rtol=0, atol=1e-12)
    torch.testing.assert_close(glnn(t, s), system.vector_field(s, "angle"), rtol=0, atol=1e-10)


def test_glnn_networks_with_zero_force_equal_lnn_with_the_same_lagrangian_network():
    system = NPendulum(2)
    glnn = GLNN(system, hidden=16, depth=2).double()
    lnn = LNN(system, hidden=16, depth=2).double()
    lnn.lagrangian_net.load_state_dict(glnn.lagrangian_net.state_dict())
    torch.nn.init.zeros_(glnn.force_net[-1].weight)
    torch.nn.init.zeros_(glnn.force_net[-1].bias)
    s = system.sample_initial(32, torch.Generator().manual_seed(5))
    torch.testing.assert_close(glnn(torch.zeros(()), s), lnn(torch.zeros(()), s), rtol=0, atol=1e-12)


def _pendulum_lagrangian(system):
    def lagrangian(s):
        q, qd = s[..., :2], s[..., 2:]
        kinetic = 0.5 * (qd[..., None, :] @ system.mass_matrix(q) @ qd[..., :, None])[..., 0, 0]
        return kinetic - system.potential(q)

    return lagrangian


def test_second_order_is_a_field_of_q_dot_and_the_network():
    system = CompoundPendulum()
    model = SecondOrder(system, hidden=8, depth=2, angular=True).double()
    s = states(system, 10)
    field = model(torch.zeros(()), s)
    torch.testing.assert_close(field[..., :2], s[..., 2:])
    torch.testing.assert_close(
        field[..., 2:], model.net(torch.cat([s[..., :2].cos(), s[..., :2].sin(), s[..., 2:]], -1))
    )


def damped_oscillator_solution(system, s0, t):
    """Closed-form underdamped solution (q, q̇) of m q̈ + a q̇ + k² q = 0 from s0 (N, 2) at times t (T,)."""
    gamma = system.a / (2 * system.m)
    omega = math.sqrt(system.k**2 / system.m - gamma**2)
    q0, v0 = s0[:, :1], s0[:, 1:]
    a_, b_ = q0, (v0 + gamma * q0) / omega
    decay, c, s = torch.exp(-gamma * t), torch.cos(omega * t), torch.sin(omega * t)
    q = decay * (a_ * c + b_ * s)
    qd = decay * ((b_ * omega - gamma * a_) * c - (a_ * omega + gamma * b_) * s)
    return torch.stack([q, qd], -1)


def test_damped_oscillator_energy_matches_closed_form_and_decays_monotonically():
    system = DampedOscillator(a=0.1)
    s0 = system.sample_initial(16, torch.Generator().manual_seed(6))
    t = torch.arange(401, dtype=torch.float64) * 0.05
    traj = simulate(system, s0, t, substeps=10)
    exact = damped_oscillator_solution(system, s0, t)
    torch.testing.assert_close(traj, exact, rtol=0, atol=1e-9)
    energy = system.energy(traj, "angle")
    torch.testing.assert_close(energy, system.energy(exact, "angle"), rtol=0, atol=1e-9)
    assert bool((energy.diff(dim=-1) <= 1e-12).all())
    assert bool((energy[:, -1] < 0.5 * energy[:, 0]).all())  # e^{-a t} = e^{-2}: it does decay


def test_compound_pendulum_energy_decays_at_the_friction_rate():
    system = CompoundPendulum()
    s = states(system)
    de_dt = torch.func.jvp(lambda x: system.energy(x, "angle"), (s,), (system.vector_field(s, "angle"),))[1]
    qd = s[..., 2:]
    torch.testing.assert_close(de_dt, -0.5 * qd[..., 0] ** 2 - 0.5 * (qd[..., 0] - qd[..., 1]) ** 2, rtol=0, atol=1e-10)
    traj = simulate(
        system,
        system.sample_initial(8, torch.Generator().manual_seed(1)),
        torch.arange(201, dtype=torch.float64) * 0.02,
        substeps=10,
    )
    assert bool((system.energy(traj, "angle").diff(dim=-1) <= 1e-12).all())


@pytest.mark.parametrize("system", list(SYSTEMS))
@pytest.mark.parametrize("model", ["glnn", "second_order"])
def test_trains_end_to_end(train_run, model, system):
    metrics = train_run([f"model={model}", f"system={system}"])
    assert math.isfinite(metrics["test/traj_rel_err"])
    assert math.isfinite(metrics["test/energy_abs_err"])


def _evaluated(tmp_path, system: str, model_of) -> dict[str, float]:
    """The test metrics of ``model_of(system)`` put into a tiny run of ``system`` (second_order built, then swapped)."""
    from encons.entry import api
    from encons.training.runs import Run

    cfg = api.compose(
        "debug=fast",
        f"system={system}",
        "model=second_order",
        "data.n_test=3",
        "data.n_steps=20",
        "data.test_steps=40",
        output_dir=tmp_path / system,
        cache_dir=tmp_path / "cache",
    )
    data, module = api.build(cfg)
    module.model = model_of(module.system)
    return api.evaluate(Run(module, data, cfg, tmp_path / system))


@pytest.mark.parametrize("name", SYSTEMS)
def test_accel_mse_of_the_true_field_is_zero(tmp_path, name):
    """GLNN fed the true L and F (the true field, by the model's own code path) scores accel_mse ~0."""

    def true_glnn(system):
        model = GLNN(system, hidden=8, depth=2, guard=0.0)
        model.lagrangian_derivatives = partial(lagrangian_derivatives, system.lagrangian)
        model.force = system.force
        return model

    metrics = _evaluated(tmp_path, name, true_glnn)
    assert 0 <= metrics["test/accel_mse"] < 1e-20


def test_accel_mse_of_zero_acceleration_is_the_mean_square_of_the_true_q_ddot(tmp_path):
    """q̈ ≡ 0 scores the mean over the held-out states (the test trajectories' first n_steps + 1) of
    q̈² = (a q̇ + k² q)², the damped oscillator's closed form, and not of the states beyond that span."""

    def zero(system):
        model = SecondOrder(system, hidden=8, depth=2)
        torch.nn.init.zeros_(model.net[-1].weight), torch.nn.init.zeros_(model.net[-1].bias)
        return model

    metrics = _evaluated(tmp_path, "damped_oscillator", zero)
    from encons.entry import api

    cfg = api.compose(
        "debug=fast",
        "system=damped_oscillator",
        "model=second_order",
        "data.n_test=3",
        "data.n_steps=20",
        "data.test_steps=40",
        cache_dir=tmp_path / "cache",
    )
    data = api.build(cfg)[0]
    data.setup()
    s = data.arrays["test"]["states"]
    a, k = cfg.system.a, cfg.system.k
    q_ddot = a * s[..., 1] + k**2 * s[..., 0]
    expected = (q_ddot[:, :21] ** 2).mean().item()
    assert metrics["test/accel_mse"] == pytest.approx(expected, rel=1e-12)
    assert expected != pytest.approx((q_ddot**2).mean().item(), rel=1e-3)  # the span matters


def test_a_discrete_model_on_these_systems_trains_and_scores_no_accel_mse(train_run):
    """Both systems choose the acceleration evaluator; a discrete model (no field) still trains and tests."""
    metrics = train_run(["model=symo", "system=damped_oscillator"])
    assert math.isfinite(metrics["test/traj_rel_err"]) and "test/accel_mse" not in metrics
