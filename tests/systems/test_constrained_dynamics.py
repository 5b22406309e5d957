"""Constrained dynamics of ``encons.systems.constrained`` against dense and finite-difference forms."""

from __future__ import annotations

import pytest
import torch
from torch.func import jacfwd, jvp, vmap

from encons.systems.base import point_mass_matrix
from encons.systems.constrained import (
    constrained_acceleration,
    constrained_hamiltonian_field,
    constraint_jacobians,
    eliminate_linear,
    full_mass_matrix,
    jacobians,
)
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum

SYSTEMS = {"pendulum2": lambda: NPendulum(2, masses=[1.0, 1.5], lengths=[1.0, 0.8]), "gyroscope": Gyroscope}


def random_masses(system, generator):
    params = [torch.rand(len(b), generator=generator, dtype=torch.float64) + 0.2 for b in system.layout.bodies]
    return full_mass_matrix(torch.linalg.inv(point_mass_matrix(system.layout, params)), system.layout.dim)


def states(system, n=16, off_manifold=0.0):
    gen = torch.Generator().manual_seed(1)
    s = system.to_chart(system.sample_initial(n, gen), "angle", "cartesian")
    return s + off_manifold * torch.randn(s.shape, generator=gen, dtype=s.dtype)


@pytest.mark.parametrize("system_name", SYSTEMS)
def test_constraint_jacobians_match_jacfwd(system_name):
    system = SYSTEMS[system_name]()
    x, v = states(system, off_manifold=0.1).chunk(2, -1)
    jac, d_rate = constraint_jacobians(system.constraints, x, v)
    assert torch.allclose(jac, vmap(jacfwd(system.constraints))(x), atol=1e-12)
    rate = lambda y, w: jvp(system.constraints, (y,), (w,))[1]  # noqa: E731
    assert torch.allclose(d_rate, vmap(jacfwd(rate))(x, v), atol=1e-12)


@pytest.mark.parametrize("off_manifold", [0.0, 0.1])
@pytest.mark.parametrize("system_name", SYSTEMS)
def test_block_form_is_the_dense_eq_20(system_name, off_manifold):
    """ż = J∇H − J DΨᵀ (DΨ J DΨᵀ)⁻¹ DΨ J∇H with DΨ by jacfwd of Ψ = (Φ, DΦ M⁻¹ p), any ∇H."""
    system = SYSTEMS[system_name]()
    gen = torch.Generator().manual_seed(2)
    minv = random_masses(system, gen)
    z = states(system, off_manifold=off_manifold)
    grad_h = torch.randn(z.shape, generator=gen, dtype=z.dtype)

    def psi(zi):
        x, p = zi.chunk(2, -1)
        return torch.cat(jvp(system.constraints, (x,), (p @ minv,)), -1)

    d = z.shape[-1] // 2
    sym = torch.cat(
        [torch.cat([torch.zeros(d, d), torch.eye(d)], 1), torch.cat([-torch.eye(d), torch.zeros(d, d)], 1)]
    ).double()
    dpsi = vmap(jacfwd(psi))(z)
    j_grad = grad_h @ sym.T
    lam = torch.linalg.solve(dpsi @ sym @ dpsi.transpose(-1, -2), (dpsi @ j_grad.unsqueeze(-1)).squeeze(-1))
    dense = j_grad - (sym @ dpsi.transpose(-1, -2) @ lam.unsqueeze(-1)).squeeze(-1)

    x, p = z.chunk(2, -1)
    jac, d_rate = constraint_jacobians(system.constraints, x, p @ minv)
    block = constrained_hamiltonian_field(grad_h, jac, d_rate, minv)
    assert torch.allclose(block, dense, atol=1e-9 * dense.abs().max())
    assert not torch.allclose(block, j_grad, atol=1e-3)  # the projection does act

    # the gyroscope's 3 constant pivot rows eliminated: 6 distance rows, M_P⁻¹ and P₂, same ż
    minv_p, project = eliminate_linear(system.constraints, minv)
    jac_r, d_rate_r = jacobians(system.constraints, x, p @ minv, linear_rows=project is None)
    assert (project is not None) == (system_name == "gyroscope")
    assert jac_r.shape[-2] == jac.shape[-2] - (3 if system_name == "gyroscope" else 0)
    grad_p = grad_h[..., d:] if project is None else grad_h[..., d:] @ project.T
    reduced = constrained_hamiltonian_field(torch.cat([grad_h[..., :d], grad_p], -1), jac_r, d_rate_r, minv_p, project)
    assert torch.allclose(reduced, dense, atol=1e-9 * dense.abs().max())


@pytest.mark.parametrize("system_name", SYSTEMS)
def test_eq_15_with_linear_rows_eliminated_is_the_dense_solve_off_the_manifold(system_name):
    """ẍ = M⁻¹(Aᵀλ − ∇V), (A M⁻¹ Aᵀ) λ = A M⁻¹ ∇V − C v over every row of Φ, as one dense solve."""
    system = SYSTEMS[system_name]()
    gen = torch.Generator().manual_seed(4)
    minv = random_masses(system, gen)
    x, v = states(system, off_manifold=0.1).chunk(2, -1)
    grad_v = torch.randn(x.shape, generator=gen, dtype=x.dtype)
    jac, d_rate = constraint_jacobians(system.constraints, x, v)
    rhs = (jac @ minv @ grad_v.unsqueeze(-1) - d_rate @ v.unsqueeze(-1)).squeeze(-1)
    lam = torch.linalg.solve(jac @ minv @ jac.transpose(-1, -2), rhs)
    dense = ((jac.transpose(-1, -2) @ lam.unsqueeze(-1)).squeeze(-1) - grad_v) @ minv
    assert torch.allclose(
        constrained_acceleration(x, v, minv, grad_v, system.constraints), dense, atol=1e-9 * dense.abs().max()
    )


@pytest.mark.parametrize("system_name", SYSTEMS)
def test_eq_20_and_eq_15_agree_on_the_manifold(system_name):
    """On Φ = 0, Φ̇ = 0 the Hamiltonian field is ẋ = v, ṗ = M ẍ with ẍ of eq. (15)."""
    system = SYSTEMS[system_name]()
    gen = torch.Generator().manual_seed(3)
    minv = random_masses(system, gen)
    x, v = states(system).chunk(2, -1)
    grad_v = torch.randn(x.shape, generator=gen, dtype=x.dtype)
    jac, d_rate = constraint_jacobians(system.constraints, x, v)
    p_dot = constrained_hamiltonian_field(torch.cat([grad_v, v], -1), jac, d_rate, minv).chunk(2, -1)[1]
    assert torch.allclose(p_dot @ minv, constrained_acceleration(x, v, minv, grad_v, system.constraints), atol=1e-9)
