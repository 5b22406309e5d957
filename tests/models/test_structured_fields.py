"""Structured models: the fast fields (one network forward, Cholesky solves) equal
the textbook ones built from the same learned M(q) and V(q), with the shared trunk and with two networks."""

from __future__ import annotations

import pytest
import torch
from torch.func import grad, hessian, vmap

from encons.models.hnn import HNNStructure
from encons.models.lnn import LNNStructure
from encons.systems.base import split_state
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum

SYSTEMS = {"pendulum2": lambda: NPendulum(2), "gyroscope": Gyroscope}


def model_and_states(cls, system_name, shared_trunk):
    system = SYSTEMS[system_name]()
    torch.manual_seed(0)
    model = cls(system, hidden=16, depth=2, shared_trunk=shared_trunk, angular=True).double()
    s = system.sample_initial(32, torch.Generator().manual_seed(1))
    return model, s


@pytest.mark.parametrize("shared_trunk", [True, False])
@pytest.mark.parametrize("system_name", SYSTEMS)
def test_hnn_structure_hamiltonian_is_the_textbook_one(system_name, shared_trunk):
    model, s = model_and_states(HNNStructure, system_name, shared_trunk)
    z = model.to_internal(s)
    q, p = split_state(z)
    textbook = 0.5 * (p * torch.linalg.solve(model.mass(q), p)).sum(-1) + model.potential(q)
    assert (model.hamiltonian(z) - textbook).abs().max() < 1e-10 * textbook.abs().max()
    assert (model.from_internal(z) - s).abs().max() < 1e-10 * s.abs().max()


@pytest.mark.parametrize("shared_trunk", [True, False])
@pytest.mark.parametrize("system_name", SYSTEMS)
def test_lnn_structure_field_is_the_euler_lagrange_one(system_name, shared_trunk):
    """q̈ = (∇²_q̇ L)⁻¹ (∇_q L − ∇_q̇ ∇_qᵀ L q̇) by full per-sample Hessians of L = ½ q̇ᵀ M q̇ − V."""
    model, s = model_and_states(LNNStructure, system_name, shared_trunk)
    n = model.n

    def lagrangian(si):
        q, qd = si[:n], si[n:]
        return 0.5 * qd @ model.mass(q[None])[0] @ qd - model.potential(q[None])[0]

    def acceleration(si):
        dl, hess = grad(lagrangian)(si), hessian(lagrangian)(si)
        return torch.linalg.solve(hess[n:, n:], dl[:n] - hess[n:, :n] @ si[n:])

    textbook = vmap(acceleration)(s)
    fast = model(torch.zeros(()), s)[:, n:]
    assert (fast - textbook).abs().max() < 1e-8 * textbook.abs().max()
