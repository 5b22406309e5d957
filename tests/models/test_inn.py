"""inn_node (Lim & Kasim §3.2) and nsf (Chen et al. 2021): inverses, eq. (6), conservation laws."""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.func import grad, jacfwd, jacrev, vmap
from torchdiffeq import odeint

from encons.models import nsf
from encons.models.inn import INNNODE, InvertibleNet
from encons.models.nsf import NSF
from encons.numerics.integrators import Integrator, rollout, state_derivative
from encons.numerics.regularisers import Hamiltonian, field_jacobian, hamiltonian_violation
from encons.systems.mass_spring import MassSpring
from encons.systems.pendulum import NPendulum
from tests.numerics.test_regularisers import HamiltonianField


def scramble(inn: nn.Module, scale: float = 0.3) -> None:
    """Give every parameter (zero-initialised coupling outputs included) random values."""
    with torch.no_grad():
        for p in inn.parameters():
            p.copy_(scale * torch.randn_like(p))


def test_inn_inverts_to_1e_5_in_float32():
    torch.manual_seed(0)
    inn = InvertibleNet(4, blocks=8, hidden=32)
    scramble(inn, 0.05)
    x = torch.randn(256, 4)
    assert (inn(x) - x).abs().max() > 1.0
    assert (inn.inverse(inn(x)) - x).abs().max() < 1e-5
    assert (inn(inn.inverse(x)) - x).abs().max() < 1e-5


def test_fresh_inn_is_a_rotation():
    torch.manual_seed(1)
    x = torch.randn(16, 5)
    y = InvertibleNet(5, blocks=3)(x)
    assert torch.allclose(y.norm(dim=-1), x.norm(dim=-1), atol=1e-5)


def latent_hamiltonian_model(seed: int = 0) -> INNNODE:
    """inn_node on a double pendulum, random INN, latent field J∇H of a random MLP H (float64)."""
    torch.manual_seed(seed)
    model = INNNODE(NPendulum(n_links=2), hidden=8, depth=1, blocks=4, block_hidden=16).double()
    scramble(model.inn, 0.2)
    model.net = HamiltonianField(4).double()
    return model


def latent_energy(model: INNNODE, s: Tensor) -> Tensor:
    """H'(s) = H(g(s))."""
    return model.net.h(model.to_internal(s)).squeeze(-1)


def test_pushed_back_field_is_eq_6():
    """ṡ = G⁻¹ J G⁻ᵀ ∇H'(s) with G = ∂g/∂s, H' = H ∘ g (Lim & Kasim eq. (6))."""
    model = latent_hamiltonian_model()
    s = torch.randn(8, 4, dtype=torch.float64)
    g_inv = torch.linalg.inv(vmap(jacrev(model.to_internal))(s))
    j = torch.tensor([[0, 0, 1, 0], [0, 0, 0, 1], [-1, 0, 0, 0], [0, -1, 0, 0]], dtype=torch.float64)
    grad_h = vmap(grad(lambda x: latent_energy(model, x)))(s)
    expected = (g_inv @ j @ g_inv.transpose(-1, -2) @ grad_h.unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(state_derivative(model, s), expected, atol=1e-10)


def test_pushed_back_latent_hamiltonian_field_conserves_h_prime():
    """Integrating ṡ of eq. (6) in data coordinates keeps H'(s) constant (Theorem 3.2)."""
    model = latent_hamiltonian_model(1)
    s0 = 0.5 * torch.randn(4, 4, dtype=torch.float64)
    t = torch.linspace(0, 2, 5, dtype=torch.float64)
    with torch.no_grad():
        traj = odeint(lambda _, s: state_derivative(model, s), s0, t, method="dopri5", rtol=1e-8, atol=1e-10)
        energy = latent_energy(model, traj)
        latent = rollout(model, s0, t, Integrator("dopri5", rtol=1e-8, atol=1e-10))
    assert (traj[-1] - traj[0]).abs().max() > 1e-2
    assert (energy - energy[0]).abs().max() < 1e-6
    assert torch.allclose(latent, traj.movedim(0, 1), atol=1e-5)


def test_hamiltonian_regulariser_acts_on_the_latent_field_eq_7():
    model = latent_hamiltonian_model(2)
    s = torch.randn(16, 4, dtype=torch.float64)
    assert Hamiltonian()(model, s).item() < 1e-10
    pushed = field_jacobian(lambda x: state_derivative(model, x), s)
    assert hamiltonian_violation(pushed).mean().item() > 1e-3


def test_nsf_with_canonical_one_form_and_true_energy_is_the_true_field():
    """θ = (p, 0) on s = (q, p) gives W = Jᵀ (∂θ/∂s constant), and W ṡ = ∇E then is Hamilton's field."""
    system = MassSpring(mass=1.0, stiffness=2.0)
    s = torch.randn(10, 2, dtype=torch.float64)
    dtheta = torch.tensor([[0.0, 0.0], [1.0, 0.0]], dtype=torch.float64)  # D_ij = ∂θ_j/∂s_i: only ∂θ_q/∂p = 1
    w = (dtheta - dtheta.T).expand(10, 2, 2)
    grad_e = vmap(grad(lambda x: system.energy(x, "angle")))(s)
    assert torch.allclose(nsf.field(w, grad_e), system.vector_field(s, "angle"), atol=1e-12)


def test_nsf_closed_form_equals_autodiff_of_its_networks():
    """W from θ's tape and ∇H from H's equal jacfwd/grad of the networks per state, and so does the field."""
    torch.manual_seed(5)
    model = NSF(NPendulum(n_links=2), hidden=16, depth=2).double()
    s = torch.randn(6, 3, 4, dtype=torch.float64)
    d = vmap(vmap(jacfwd(model.one_form)))(s)  # d[..., j, i] = ∂θ_j/∂s_i
    w = d.transpose(-1, -2) - d
    assert torch.allclose(model.symplectic_matrix(s), w, atol=1e-12)
    grad_h = vmap(vmap(grad(model.hamiltonian)))(s)
    want = torch.linalg.solve(w, grad_h.unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(model(torch.zeros(()), s), want, atol=1e-9)


def test_nsf_conserves_its_learned_hamiltonian():
    """W is skew-symmetric, so dH/dt = ∇Hᵀ W⁻¹ ∇H = 0 for any learned θ and H."""
    torch.manual_seed(3)
    model = NSF(NPendulum(n_links=2), hidden=16, depth=2).double()
    s = torch.randn(32, 4, dtype=torch.float64)
    rate = (vmap(grad(model.hamiltonian))(s) * model(torch.zeros(()), s)).sum(-1)
    assert rate.abs().max() < 1e-9
    w = model.symplectic_matrix(s)
    assert torch.allclose(w, -w.transpose(-1, -2))


def test_nsf_field_jacobian_is_the_same_in_forward_and_reverse_mode():
    """Guards the explicit inverse in NSF: vmap(jacfwd(linalg.solve)) is wrong in torch 2.13."""
    torch.manual_seed(4)
    model = NSF(NPendulum(n_links=2), hidden=16, depth=2).double()
    s = torch.randn(8, 4, dtype=torch.float64)
    z, field = model.constrained_field(s)
    assert torch.allclose(field_jacobian(field, z, "forward"), field_jacobian(field, z, "reverse"), atol=1e-8)
