"""The energy-conserving models fed the true physics reproduce the true dynamics (float64).

Each model exposes its learned pieces under one name (``hamiltonian``, ``lagrangian``,
``mass``, ``potential``, ``point_masses``); swapping in the system's own quantities must give
the system's vector field, and Cartesian models must keep Φ = 0 and Φ̇ = 0 along a rollout.
The fields differentiate the models' own networks in closed form (``hamiltonian_gradient``,
``lagrangian_derivatives``, ``euler_lagrange_terms``, ``potential_gradient``); with swapped-in
pieces they take the autodiff versions of the same (tests/models/test_closed_form_fields.py: equal).
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
import torch
from torch.func import jvp

from encons.infra.batching import batched_grad
from encons.infra.errors import ConfigError
from encons.models.constrained import CHNN, CLNN, CartesianModel
from encons.models.hnn import HNN, HNNStructure
from encons.models.lnn import LNN, LNNStructure, euler_lagrange_terms, lagrangian_derivatives
from encons.numerics.integrators import Integrator, rollout, state_derivative
from encons.systems.base import split_state
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum

ANGLE_MODELS = [
    partial(cls, angular=angular) for cls in (HNN, HNNStructure, LNN, LNNStructure) for angular in (False, True)
]
MODELS = ANGLE_MODELS + [CHNN, CLNN]


def model_id(cls) -> str:
    """HNN, HNN_angle, ...: a class, or a partial of one with ``angular``."""
    if isinstance(cls, partial):
        return cls.func.__name__ + ("_angle" if cls.keywords.get("angular") else "")
    return cls.__name__


SYSTEMS = {"pendulum2": lambda: NPendulum(2, masses=[1.0, 1.5], lengths=[1.0, 0.8]), "gyroscope": Gyroscope}


class TrueMass(torch.nn.Module):
    """The system's M(q) behind the interface of ``CholeskyMass``."""

    def __init__(self, system):
        super().__init__()
        self.system = system

    def forward(self, q):
        return self.system.mass_matrix(q)

    def solve(self, q, p):
        return torch.linalg.solve(self.system.mass_matrix(q), p.unsqueeze(-1)).squeeze(-1)

    def cholesky(self, q):
        return torch.linalg.cholesky(self.system.mass_matrix(q))


def with_true_physics(model, system, potential_scale=1.0):
    """Swap the system's own physical quantities into ``model`` (V scaled by ``potential_scale``)."""
    if isinstance(model, CartesianModel):
        model.potential = lambda x: potential_scale * system.cartesian_potential(x)
        model.potential_gradient = partial(batched_grad, model.potential)
        model.point_masses = system.point_masses
        model.point_masses_inverse = lambda: torch.linalg.inv(system.point_masses())
        return model
    mass = TrueMass(system)

    def potential(q):
        return potential_scale * system.potential(q)

    def kinetic(q, qd):
        return 0.5 * (qd * (mass(q) @ qd.unsqueeze(-1)).squeeze(-1)).sum(-1)

    if isinstance(model, LNN):
        model.lagrangian = lambda s: kinetic(*split_state(s)) - potential(split_state(s)[0])
        model.lagrangian_derivatives = partial(lagrangian_derivatives, model.lagrangian)
    elif isinstance(model, HNN):
        model.mass = mass
        model.hamiltonian = lambda z: (
            kinetic(split_state(z)[0], mass.solve(*split_state(z))) + potential(split_state(z)[0])
        )
    else:
        model.mass = mass
        model.factor_potential = lambda q: (mass.cholesky(q), potential(q))
        model.euler_lagrange_terms = partial(euler_lagrange_terms, model.factor_potential)
    if isinstance(model, (HNN, HNNStructure)):
        model.hamiltonian_gradient = partial(batched_grad, model.hamiltonian)
    return model


def angle_states(system, n=48):
    """Random states of the angle chart, away from the gyroscope's gimbal lock (sin θ = 0)."""
    s = system.sample_initial(4 * n, torch.Generator().manual_seed(7))
    if isinstance(system, Gyroscope):
        s = s[torch.sin(s[:, 1]).abs() > 0.3]
    return s[:n]


def build(cls, system):
    model = cls(system, hidden=16, depth=2).double()
    states = angle_states(system)
    return model, system.to_chart(states, "angle", model.chart)


def relative_gap(a, b):
    return ((a - b).abs().max() / b.abs().max()).item()


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("cls", MODELS, ids=model_id)
def test_true_physics_gives_the_true_field(cls, system_name):
    system = SYSTEMS[system_name]()
    model, s = build(cls, system)
    truth = system.vector_field(s, model.chart)
    assert relative_gap(state_derivative(with_true_physics(model, system), s), truth) < 1e-10
    assert relative_gap(state_derivative(with_true_physics(model, system, 1.05), s), truth) > 1e-4


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("cls", [CHNN, CLNN], ids=lambda c: c.__name__)
def test_cartesian_models_match_generalised_coordinates(cls, system_name):
    """Independent of eq. (15): the angle-chart field pushed to the Cartesian chart by ``to_chart``."""
    system = SYSTEMS[system_name]()
    s = angle_states(system)
    to_cartesian = lambda u: system.to_chart(u, "angle", "cartesian")  # noqa: E731
    x, pushed = jvp(to_cartesian, (s,), (system.vector_field(s, "angle"),))
    model = with_true_physics(cls(system, hidden=16, depth=2).double(), system)
    assert relative_gap(state_derivative(model, x), pushed) < 1e-10


def constraint_violation(system, traj):
    x, v = split_state(traj)
    phi, phi_dot = jvp(system.constraints, (x,), (v,))
    return phi.abs().max().item(), phi_dot.abs().max().item()


def constrained_rollout(model, system, steps=100):
    """``steps`` RK4 steps (2 per data dt) from 8 Cartesian states."""
    dt = 0.02 if isinstance(system, Gyroscope) else 0.03
    x0 = system.to_chart(angle_states(system, 8), "angle", "cartesian")
    return rollout(model, x0, torch.arange(steps + 1, dtype=torch.float64) * dt, Integrator("rk4", substeps=2))


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("cls", [CHNN, CLNN], ids=lambda c: c.__name__)
def test_rollout_keeps_the_constraints_and_energy(cls, system_name):
    system = SYSTEMS[system_name]()
    traj = constrained_rollout(with_true_physics(cls(system, hidden=16, depth=2).double(), system), system)
    phi, phi_dot = constraint_violation(system, traj)
    assert phi < 5e-3 and phi_dot < 5e-3, (phi, phi_dot)
    energy = system.energy(traj, "cartesian")
    assert (energy - energy[:, :1]).abs().max() < 5e-3 * energy.abs().max()


@pytest.mark.parametrize("cls", [CHNN, CLNN], ids=lambda c: c.__name__)
def test_untrained_rollout_keeps_the_constraints(cls):
    """The constraints hold whatever V and masses the model has learned."""
    system = SYSTEMS["pendulum2"]()
    model = cls(system, hidden=16, depth=2).double()
    torch.manual_seed(0)
    for p in model.masses.log_params:
        torch.nn.init.uniform_(p, -1.0, 1.0)
    phi, phi_dot = constraint_violation(system, constrained_rollout(model, system))
    assert phi < 5e-3 and phi_dot < 5e-3, (phi, phi_dot)


def test_dropping_a_constraint_breaks_it():
    """The checks above can fail: without the second rod's constraint the second bob falls freely."""
    system = SYSTEMS["pendulum2"]()
    model = with_true_physics(CLNN(system, hidden=16, depth=2).double(), system)
    model.constraints = lambda x: system.constraints(x)[..., :1]
    assert constraint_violation(system, constrained_rollout(model, system, steps=20))[0] > 1e-1


@pytest.mark.parametrize("model", ["chnn", "clnn"])
def test_cartesian_model_on_a_system_without_constraints(tmp_path, train_run, model):
    system = NPendulum(1)
    traj = system.to_chart(system.sample_initial(8, torch.Generator().manual_seed(0)), "angle", "cartesian")
    path = tmp_path / "points.npz"
    np.savez(
        path,
        t=np.arange(2) * 0.03,
        train=traj[:, None].repeat(1, 2, 1).numpy(),
        test=traj[:, None].repeat(1, 2, 1).numpy(),
        chart=np.array("cartesian"),
    )
    with pytest.raises(ConfigError, match=r"needs holonomic constraints.*'from_file'"):
        train_run(["system=from_file", f"system.path={path}", f"model={model}"])
