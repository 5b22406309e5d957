"""Lim & Kasim's soft constraints: C_H (eq. 4) and C_D (eq. 8) against closed forms."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor, nn
from torch.func import grad

from encons.infra.batching import batched
from encons.infra.errors import ConfigError
from encons.models.networks import mlp
from encons.models.node import NODE
from encons.numerics.regularisers import (
    Dissipative,
    Hamiltonian,
    dissipative_violation,
    field_jacobian,
    from_paper_weight,
    hamiltonian_violation,
)
from encons.systems.base import split_state
from encons.systems.mass_spring import MassSpring
from encons.systems.pendulum import NPendulum


class HamiltonianField(nn.Module):
    """J∇H − γ (0, p) of a random MLP H (γ = 0: an exact Hamiltonian field)."""

    def __init__(self, dim: int, damping: float = 0.0):
        super().__init__()
        self.h, self.damping = mlp(dim, 1, 32, 2, "tanh"), damping

    def forward(self, z: Tensor) -> Tensor:
        dq, dp = split_state(batched(grad(lambda x: self.h(x).squeeze(-1)), z))
        _, p = split_state(z)
        return torch.cat([dp, -dq - self.damping * p], -1)


def node_with(field: nn.Module, n: int) -> NODE:
    system = MassSpring() if n == 1 else NPendulum(n_links=n)
    model = NODE(system, hidden=8, depth=1).double()
    model.net = field.double()
    return model


def linear(matrix: Tensor) -> nn.Linear:
    layer = nn.Linear(matrix.shape[0], matrix.shape[0], bias=False)
    layer.weight.data = matrix.clone()
    return layer


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("mode", ["reverse", "forward"])
def test_hamiltonian_penalty_vanishes_on_any_hamiltonian_field(n, mode):
    torch.manual_seed(n)
    model = node_with(HamiltonianField(2 * n), n)
    s = torch.randn(32, 2 * n, dtype=torch.float64)
    assert Hamiltonian(weight=1.0, jacobian=mode)(model, s).item() < 1e-10


def test_hamiltonian_penalty_of_damped_oscillator_is_closed_form():
    """A = [[0, 1], [−1, −γ]]: Jᵀ A − Aᵀ J = [[0, γ], [−γ, 0]], so C_H = 2γ²."""
    gamma = 0.3
    model = node_with(linear(torch.tensor([[0.0, 1.0], [-1.0, -gamma]], dtype=torch.float64)), 1)
    s = torch.randn(8, 2, dtype=torch.float64)
    assert Hamiltonian(weight=5.0)(model, s).item() == pytest.approx(5.0 * 2 * gamma**2, rel=1e-12)


def test_hamiltonian_penalty_is_positive_for_a_damped_nonlinear_field():
    torch.manual_seed(0)
    model = node_with(HamiltonianField(4, damping=0.1), 2)
    assert Hamiltonian()(model, torch.randn(16, 4, dtype=torch.float64)).item() > 1e-3


def rotation_block(sigma: float, omega: float) -> Tensor:
    """Real 2×2 block with eigenvalues σ ± iω."""
    return torch.tensor([[sigma, omega], [-omega, sigma]], dtype=torch.float64)


def similar(blocks: Tensor, seed: int = 0) -> Tensor:
    """P B P⁻¹ for a random well-conditioned P: same eigenvalues as B."""
    gen = torch.Generator().manual_seed(seed)
    p = torch.eye(len(blocks), dtype=torch.float64) + 0.3 * torch.randn(
        len(blocks), len(blocks), generator=gen, dtype=torch.float64
    )
    return p @ blocks @ torch.linalg.inv(p)


@pytest.mark.parametrize("sigma, bound, expected", [(-0.2, 0.0, 0.0), (-0.2, -0.5, 2 * 0.3**2), (0.1, 0.0, 2 * 0.1**2)])
def test_dissipative_penalty_of_linear_field_is_closed_form(sigma, bound, expected):
    model = node_with(linear(similar(rotation_block(sigma, 1.3))), 1)
    value = Dissipative(weight=1.0, bound=bound)(model, torch.randn(4, 2, dtype=torch.float64)).item()
    assert value == pytest.approx(expected, abs=1e-12)


def test_dissipative_bounds_per_eigenvalue_follow_decreasing_real_parts():
    """Eigenvalues 0.5, −0.1 ± 2i, −1 against a = (0, 0, −0.5, −2): only 0.5 and one −0.1 exceed."""
    blocks = torch.block_diag(torch.tensor([[0.5]]), rotation_block(-0.1, 2.0), torch.tensor([[-1.0]])).double()
    model = node_with(linear(similar(blocks, 1)), 2)
    value = Dissipative(bound=[0.0, 0.0, -0.5, -2.0])(model, torch.randn(3, 4, dtype=torch.float64)).item()
    assert value == pytest.approx(0.5**2 + 0.4**2 + 1.0**2, abs=1e-10)
    with pytest.raises(ConfigError, match="regulariser.bound"):
        Dissipative(bound=[0.0, 0.0, 0.0])(model, torch.randn(3, 4, dtype=torch.float64))


@pytest.mark.parametrize("penalty", [Hamiltonian(), Dissipative(bound=-3.0)])
def test_penalty_gradients_reach_every_parameter_and_match_finite_differences(penalty):
    torch.manual_seed(1)
    model = NODE(NPendulum(n_links=2), hidden=16, depth=2, activation="tanh").double()
    s = torch.randn(6, 4, dtype=torch.float64)
    value = penalty(model, s)
    assert value.item() > 0
    value.backward()
    weights = [p for name, p in model.named_parameters() if name.endswith("weight")]  # the last bias cannot count
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in weights)
    weight = model.net[0].weight
    direction = torch.randn_like(weight)
    with torch.no_grad():
        weight += 1e-6 * direction
        up = penalty(model, s).item()
        weight -= 2e-6 * direction
        down = penalty(model, s).item()
    assert (up - down) / 2e-6 == pytest.approx((weight.grad * direction).sum().item(), rel=1e-5)


def test_forward_and_reverse_jacobians_agree_with_finite_differences():
    torch.manual_seed(2)
    field = mlp(4, 4, 16, 2, "softplus").double()
    z = torch.randn(5, 4, dtype=torch.float64)
    eps = 1e-6
    fd = torch.stack([(field(z + eps * e) - field(z - eps * e)) / (2 * eps) for e in torch.eye(4).double()], -1)
    for mode in ("forward", "reverse"):
        assert torch.allclose(field_jacobian(field, z, mode), fd, atol=1e-8)


def test_bad_regulariser_settings_are_config_errors():
    with pytest.raises(ConfigError, match="regulariser.weight"):
        Hamiltonian(weight=-1.0)
    with pytest.raises(ConfigError, match="regulariser.jacobian"):
        Dissipative(jacobian="sideways")
    assert math.isclose(Dissipative(weight=2).weight, 2.0)


@pytest.mark.parametrize(
    "constraint, violation",
    [("hamiltonian", hamiltonian_violation), ("dissipative", lambda a: dissipative_violation(a, torch.zeros(())))],
)
def test_paper_weight_makes_the_papers_entry_mean_loss_proportional_to_encons_sum(constraint, violation):
    gen = torch.Generator().manual_seed(0)
    d, w = 4, 1e3
    err, jac = (
        torch.randn(16, d, generator=gen, dtype=torch.float64),
        torch.randn(16, d, d, generator=gen, dtype=torch.float64),
    )
    entries = d * d if constraint == "hamiltonian" else d  # what the authors' code averages over
    paper = (err**2).mean(-1).mean() + w * (violation(jac) / entries).mean()
    ours = (err**2).sum(-1).mean() + from_paper_weight(w, constraint, d) * violation(jac).mean()
    assert float(ours) == pytest.approx(float(d * paper), rel=1e-12)
