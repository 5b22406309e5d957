"""HNN and HNN-angle (Greydanus et al. 2019, as benchmarked in Zhong et al. §3).

A network H(q, p) gives q̇ = ∂H/∂p, ṗ = −∂H/∂q (Zhong et al. eq. (6)). Data hold (q, q̇)
only, so a learned M(q) = L Lᵀ maps q̇ → p = M(q) q̇ at the start of a rollout and
p → q̇ = M(q)⁻¹ p on the way out.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.func import grad

from encons.batching import batched
from encons.models.base import DynamicsModel
from encons.models.networks import CholeskyMass, embed_angles, mlp
from encons.systems.base import System, split_state


class HNN(DynamicsModel):
    """Unstructured Hamiltonian in generalised coordinates; ``angular`` embeds q on S¹."""

    default_chart = "angle"
    angular = False

    def __init__(self, system: System, chart: str | None = None, hidden: int = 256, depth: int = 3,
                 activation: str = "softplus", mass_eps: float = 1e-3):
        super().__init__(system, chart)
        n = self.n
        self.hamiltonian_net = mlp(3 * n if self.angular else 2 * n, 1, hidden, depth, activation)
        self.mass = CholeskyMass(n, self.angular, hidden, depth, activation, mass_eps)

    def hamiltonian(self, z: Tensor) -> Tensor:
        """H(q, p) of internal states (..., 2n)."""
        q, p = split_state(z)
        return self.hamiltonian_net(torch.cat([embed_angles(q, self.angular), p], -1)).squeeze(-1)

    def encode(self, s: Tensor) -> Tensor:
        q, qd = split_state(s)
        return torch.cat([q, (self.mass(q) @ qd.unsqueeze(-1)).squeeze(-1)], -1)

    def decode(self, z: Tensor) -> Tensor:
        q, p = split_state(z)
        return torch.cat([q, self.mass.solve(q, p)], -1)

    def forward(self, t: Tensor, z: Tensor) -> Tensor:
        dh = batched(grad(self.hamiltonian), z)
        dq, dp = split_state(dh)
        return torch.cat([dp, -dq], -1)


class HNNAngle(HNN):
    """HNN with each angle embedded as (cos q, sin q) (Zhong et al. §3, "HNN-angle")."""

    angular = True
