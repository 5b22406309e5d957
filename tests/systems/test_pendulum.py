"""N-pendulum ground truth: energy conservation, constraints, chart consistency, closed forms."""

from __future__ import annotations

import math

import pytest
import torch
from torch.func import hessian

from encons.data.simulate import simulate
from encons.infra.errors import ConfigError
from encons.systems.constrained import constraint_jacobians
from encons.systems.pendulum import NPendulum

T = torch.arange(101, dtype=torch.float64) * 0.03


@pytest.fixture(scope="module")
def pendulum2():
    system = NPendulum(2)
    s0 = system.sample_initial(200, torch.Generator().manual_seed(0))
    return system, simulate(system, s0, T)


def test_energy_drift_below_1e6(pendulum2):
    system, traj = pendulum2
    energy = system.energy(traj, "angle")
    scale = system.g * (system.mu * system.l).sum()  # |V| at rest
    assert ((energy - energy[:, :1]).abs().max() / scale) < 1e-6


def test_cartesian_states_satisfy_constraints(pendulum2):
    system, traj = pendulum2
    cart = system.to_chart(traj, "angle", "cartesian")
    x, v = cart[..., :4], cart[..., 4:]
    assert system.constraints(x).abs().max() < 1e-8
    jac, _ = constraint_jacobians(system.constraints, x, v)
    assert (jac @ v[..., None]).abs().max() < 1e-8


def test_cartesian_simulation_equals_mapped_angle_simulation(pendulum2):
    system, traj = pendulum2
    cart0 = system.to_chart(traj[:8, 0], "angle", "cartesian")
    cart = simulate(_CartesianView(system), cart0, T[:51])
    mapped = system.to_chart(traj[:8, :51], "angle", "cartesian")
    assert (cart - mapped).abs().max() < 1e-5  # both carry RK4 error ~1e-6 after 50 steps
    assert system.constraints(cart[..., :4]).abs().max() < 1e-6


class _CartesianView:
    """The pendulum with the Cartesian chart as its base chart, to simulate there."""

    def __init__(self, system):
        self.system, self.base_chart = system, "cartesian"

    def vector_field(self, s, chart):
        return self.system.vector_field(s, chart)


def test_energy_agrees_between_charts(pendulum2):
    system, traj = pendulum2
    cart = system.to_chart(traj, "angle", "cartesian")
    assert torch.allclose(system.energy(traj, "angle"), system.energy(cart, "cartesian"), atol=1e-10)


def test_chart_round_trip(pendulum2):
    system, traj = pendulum2
    back = system.to_chart(system.to_chart(traj, "angle", "cartesian"), "cartesian", "angle")
    wrapped = torch.remainder(back[..., :2] - traj[..., :2] + math.pi, 2 * math.pi) - math.pi
    assert wrapped.abs().max() < 1e-10 and (back[..., 2:] - traj[..., 2:]).abs().max() < 1e-10


def test_single_pendulum_small_oscillation_period():
    """Small swings of a simple pendulum have period 2π√(l/g)."""
    system = NPendulum(1, lengths=2.0, g=9.81)
    period = 2 * math.pi * math.sqrt(2.0 / 9.81)
    t = torch.linspace(0, period, 201, dtype=torch.float64)
    traj = simulate(system, torch.tensor([[1e-3, 0.0]], dtype=torch.float64), t)
    assert abs(traj[0, -1, 0].item() - 1e-3) < 1e-8


def test_mass_matrix_is_the_lagrangian_hessian():
    system = NPendulum(3, masses=[1.0, 2.0, 0.5], lengths=[1.0, 0.7, 1.3])
    s = system.sample_initial(5, torch.Generator().manual_seed(1))

    def lagrangian(state):
        q = state[:3]
        cart = system.to_chart(state, "angle", "cartesian")
        kinetic = 0.5 * (system.m * (cart[6:].reshape(3, 2) ** 2).sum(-1)).sum()
        return kinetic - system.potential(q)

    for state in s:
        assert torch.allclose(hessian(lagrangian)(state)[3:, 3:], system.mass_matrix(state[:3]), atol=1e-12)


def test_bad_parameters_are_rejected():
    with pytest.raises(ConfigError, match="system.masses"):
        NPendulum(2, masses=[1.0])
    with pytest.raises(ConfigError, match="system.n_links"):
        NPendulum(0)
