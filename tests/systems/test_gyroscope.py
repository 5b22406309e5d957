"""Gyroscope ground truth: energy conservation, constraints, chart consistency, closed forms."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch
from torch.func import grad, hessian, jvp, vmap

from encons.data.simulate import sample_trajectories, simulate
from encons.infra.errors import ConfigError
from encons.systems.constrained import constraint_jacobians
from encons.systems.gyroscope import Gyroscope

T = torch.arange(101, dtype=torch.float64) * 0.02


@pytest.fixture(scope="module")
def gyro():
    system = Gyroscope()
    traj, _, _ = sample_trajectories(system, 100, T, torch.Generator().manual_seed(0))
    return system, traj


def test_energy_drift_below_1e6(gyro):
    system, traj = gyro
    energy = system.energy(traj, "angle")
    scale = energy[:, 0].abs().mean()
    assert ((energy - energy[:, :1]).abs().max() / scale) < 1e-6


def test_angular_momenta_conserved(gyro):
    """p_ψ = J_3 ω_3 and p_φ are conserved: ψ and φ are cyclic."""
    system, traj = gyro
    q, qd = traj[..., :3], traj[..., 3:]
    momenta = (system.mass_matrix(q) @ qd[..., None])[..., 0]
    assert (momenta[..., [0, 2]] - momenta[:, :1, [0, 2]]).abs().max() < 1e-7


def test_gimbal_lock_is_rejected(gyro):
    system, traj = gyro
    assert torch.sin(traj[..., 1]).abs().min() >= system.min_sin_theta
    crossing = torch.tensor([[0.3, 0.02, 0.1, 1.0, -0.1, 10.0]], dtype=torch.float64)
    assert not system.valid(simulate(system, crossing, T[:3])).any()


def test_min_sin_theta_zero_keeps_every_trajectory():
    """min_sin_theta=0 (profile=zhong, Zhong et al. keep gimbal lock) is accepted and rejects no finite trajectory."""
    system = Gyroscope(min_sin_theta=0.0)
    crossing = torch.tensor([[0.3, 0.02, 0.1, 1.0, -0.1, 10.0]], dtype=torch.float64)
    assert system.valid(simulate(system, crossing, T[:3])).all()


def test_cartesian_states_satisfy_constraints(gyro):
    system, traj = gyro
    cart = system.to_chart(traj[:, ::5], "angle", "cartesian")
    x, v = cart[..., :12], cart[..., 12:]
    assert system.constraints(x).abs().max() < 1e-8
    jac, _ = constraint_jacobians(system.constraints, x, v)
    assert (jac @ v[..., None]).abs().max() < 1e-8


def test_cartesian_field_is_the_pushforward_of_the_angle_field(gyro):
    """d/dt map(s) = D map(s) · f_angle(s) must equal f_cartesian(map(s))."""
    system, traj = gyro
    s = traj[:, ::10].reshape(-1, 6)
    to_cart = lambda state: system.to_chart(state, "angle", "cartesian")  # noqa: E731
    cart, pushed = jvp(to_cart, (s,), (system.vector_field(s, "angle"),))
    assert (system.vector_field(cart, "cartesian") - pushed).abs().max() < 1e-9


def test_cartesian_simulation_equals_mapped_angle_simulation(gyro):
    system, traj = gyro
    steps = 20  # 3 RK4 substeps keep the constrained field's cost down; its error is ~1e-5 here
    in_cartesian = SimpleNamespace(base_chart="cartesian", vector_field=system.vector_field)
    cart = simulate(in_cartesian, system.to_chart(traj[:4, 0], "angle", "cartesian"), T[: steps + 1], 3)
    mapped = system.to_chart(traj[:4, : steps + 1], "angle", "cartesian")
    assert (cart - mapped).abs().max() < 5e-5
    assert system.constraints(cart[..., :12]).abs().max() < 1e-5


def test_energy_agrees_between_charts(gyro):
    system, traj = gyro
    cart = system.to_chart(traj, "angle", "cartesian")
    assert torch.allclose(system.energy(traj, "angle"), system.energy(cart, "cartesian"), atol=1e-12)


def test_chart_round_trip(gyro):
    """Cartesian -> angle -> Cartesian is the identity (angles themselves are defined up to θ's sign)."""
    system, traj = gyro
    cart = system.to_chart(traj, "angle", "cartesian")
    back = system.to_chart(cart, "cartesian", "angle")
    assert (system.to_chart(back, "angle", "cartesian") - cart).abs().max() < 1e-10
    positive = traj[..., 1] > 0
    wrapped = torch.remainder(back[..., :3] - traj[..., :3] + math.pi, 2 * math.pi) - math.pi
    assert wrapped[positive].abs().max() < 1e-10 and (back - traj)[positive][:, 3:].abs().max() < 1e-10


def test_mass_matrix_is_the_lagrangian_hessian_and_field_solves_euler_lagrange():
    """M(q) = ∂²L/∂q̇² with L from Finzi's Cartesian kinetic energy; f solves M q̈ = ∇_q L − (∂²L/∂q̇∂q) q̇."""
    system = Gyroscope()
    s = system.sample_initial(8, torch.Generator().manual_seed(1))

    def lagrangian(state):
        cart = system.to_chart(state, "angle", "cartesian")
        kinetic = system.energy(cart, "cartesian") - system.cartesian_potential(cart[:12])
        return kinetic - system.potential(state[:3])

    def euler_lagrange(state):
        hess, gradient = hessian(lagrangian)(state), grad(lagrangian)(state)
        return torch.linalg.solve(hess[3:, 3:], gradient[:3] - hess[3:, :3] @ state[3:])

    hess = vmap(hessian(lagrangian))(s)
    assert torch.allclose(hess[:, 3:, 3:], system.mass_matrix(s[:, :3]), atol=1e-12)
    assert torch.allclose(vmap(euler_lagrange)(s), system.vector_field(s, "angle")[:, 3:], atol=1e-9)


def test_sleeping_top_precession_rate():
    """Steady precession at tilt θ: J⊥' φ̇² cos θ − J_3 ω_3 φ̇ + m g ℓ = 0 keeps θ fixed."""
    system = Gyroscope()
    theta, omega_3 = 0.7, 12.0
    a, b, c = system.j_perp * math.cos(theta), -system.j_3 * omega_3, system.m * system.g * system.ell
    phid = (-b - math.sqrt(b * b - 4 * a * c)) / (2 * a)  # slow precession
    s0 = torch.tensor([[0.0, theta, 0.0, phid, 0.0, omega_3 - phid * math.cos(theta)]], dtype=torch.float64)
    traj = simulate(system, s0, T)
    assert (traj[0, :, 1] - theta).abs().max() < 1e-9
    assert abs(traj[0, -1, 0].item() - phid * T[-1].item()) < 1e-9


def test_principal_moments_match_finzi():
    """Finzi's axis 'inertias' give J⊥ = I_1 + I_3 = 0.02783 and J_3 = I_1 + I_2 = 0.04828 about the centre of mass."""
    system = Gyroscope()
    assert system.j_perp - system.m * system.ell**2 == pytest.approx(0.02783, abs=5e-6)
    assert system.j_3 == pytest.approx(0.04828, abs=5e-6)


def test_bad_parameters_are_rejected():
    with pytest.raises(ConfigError, match="system.inertias"):
        Gyroscope(inertias=[0.1, 0.2, 0.3])
    with pytest.raises(ConfigError, match="system.min_sin_theta"):
        Gyroscope(min_sin_theta=1.5)
    with pytest.raises(ConfigError, match="system.mass"):
        Gyroscope(mass=-1.0)


@pytest.mark.parametrize("model", ["node", "hnn_angle"])
def test_trains_end_to_end(train_run, model):
    metrics = train_run([f"model={model}", "system=gyroscope"])
    assert math.isfinite(metrics["test/traj_rel_err"])
