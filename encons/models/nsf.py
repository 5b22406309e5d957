"""Neural symplectic form (Chen, Matsubara & Yaguchi 2021), the baseline of Lim & Kasim (2023).

A learned 1-form θ(s) (an MLP ℝ²ⁿ → ℝ²ⁿ) gives the symplectic 2-form ω = dθ with matrix
W(s) = (∂θ/∂s)ᵀ − ∂θ/∂s, i.e. W_ij = ∂_i θ_j − ∂_j θ_i; a network H(s) gives the Hamiltonian,
and the field solves W ṡ = ∇H (ι_ṡ ω = dH). For θ = (p, 0) on s = (q, p), W = Jᵀ and
ṡ = J∇H. Coordinate-free: works in any chart. W is inverted by an O(n³) solve per state.

∂θ/∂s and ∇H are taken in closed form through the two networks (``MLPTape``: θ pushed along the 2n unit
directions, H pulled back), batched over states with no per-sample transform: the same values as
``jacfwd``/``grad`` per state to rounding (``tests/models/test_inn.py``), and a seed ensemble stacks it by the
ensemble dimension.
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.bounds import Count
from encons.models.base import DynamicsModel
from encons.models.networks import MLPTape, mlp
from encons.systems.base import System


class NSF(DynamicsModel):
    """Learned 1-form and Hamiltonian; sizes default to Lim & Kasim's (2 hidden layers × 200)."""

    family = "symplectic_form"

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 200,
        depth: Count = 2,
        activation: str = "softplus",
    ):
        super().__init__(system, chart)
        self.one_form = mlp(2 * self.n, 2 * self.n, hidden, depth, activation, out_bias=False)
        self.hamiltonian_net = mlp(2 * self.n, 1, hidden, depth, activation, out_bias=False)

    def hamiltonian(self, z: Tensor) -> Tensor:
        """H(s) of states (..., 2n)."""
        return self.hamiltonian_net(z).squeeze(-1)

    def symplectic_matrix(self, z: Tensor) -> Tensor:
        """W(s) of states (..., 2n), shape (..., 2n, 2n)."""
        return symplectic_matrix(MLPTape(self.one_form, z), z)

    def forward(self, t: Tensor, z: Tensor) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (DynamicsModel)
        return field(self.symplectic_matrix(z), MLPTape(self.hamiltonian_net, z).pullback())


def symplectic_matrix(one_form: MLPTape, z: Tensor) -> Tensor:
    """W = (∂θ/∂s)ᵀ − ∂θ/∂s at states z (..., d) of a one-form θ's tape: ``push`` along the d unit directions
    gives D_ij = ∂θ_j/∂s_i, so W_ij = D_ij − D_ji."""
    d = z.shape[-1]
    dtheta, _ = one_form.push(torch.eye(d, dtype=z.dtype, device=z.device).expand(*z.shape[:-1], d, d))
    return dtheta - dtheta.transpose(-1, -2)


def field(w: Tensor, grad_h: Tensor) -> Tensor:
    """ṡ with W ṡ = ∇H, per state: W (..., d, d), ∇H (..., d)."""
    # inv, not linalg.solve: torch 2.13 gets vmap(jacfwd(linalg.solve)) wrong (the regularisers' Jacobians)
    return (torch.linalg.inv(w) @ grad_h.unsqueeze(-1)).squeeze(-1)
