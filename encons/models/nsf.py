"""Neural symplectic form (Chen, Matsubara & Yaguchi 2021), the baseline of Lim & Kasim (2023).

A learned 1-form θ(s) (an MLP ℝ²ⁿ → ℝ²ⁿ) gives the symplectic 2-form ω = dθ with matrix
W(s) = (∂θ/∂s)ᵀ − ∂θ/∂s, i.e. W_ij = ∂_i θ_j − ∂_j θ_i; a network H(s) gives the Hamiltonian,
and the field solves W ṡ = ∇H (ι_ṡ ω = dH). For θ = (p, 0) on s = (q, p), W = Jᵀ and
ṡ = J∇H. Coordinate-free: works in any chart. W is inverted by an O(n³) solve per state.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.func import grad, jacfwd

from encons.infra.batching import batched
from encons.infra.bounds import Count
from encons.models.base import DynamicsModel
from encons.models.networks import mlp
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
        """W(s) of one state (2n,), shape (2n, 2n)."""
        d = jacfwd(self.one_form)(z)
        return d.T - d

    def _field(self, z: Tensor) -> Tensor:
        # inv, not linalg.solve: torch 2.13 gets vmap(jacfwd(linalg.solve)) wrong (regularisers)
        return torch.linalg.inv(self.symplectic_matrix(z)) @ grad(self.hamiltonian)(z)

    def forward(self, t: Tensor, z: Tensor) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (DynamicsModel)
        return batched(self._field, z)
