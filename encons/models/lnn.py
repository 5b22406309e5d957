"""Lagrangian models in generalised coordinates (Zhong et al. §3): LNN, LNN-structure, "-angle".

The state is s = (q, q̇) and the field ṡ = (q̇, q̈) with q̈ from the Euler–Lagrange equations
of a learned Lagrangian. ``angular=True`` (the "-angle" variants, ``model=*_angle``) embeds each
angle as (cos q, sin q).
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor
from torch.func import grad, jvp, vjp, vmap

from encons.batching import batched_grad
from encons.models.base import DynamicsModel
from encons.models.networks import embed_angles, mlp
from encons.models.structured import MassPotentialModel
from encons.systems.base import System, split_state


def euler_lagrange_acceleration(lagrangian: Callable[[Tensor], Tensor], s: Tensor) -> Tensor:
    """q̈ of Zhong et al. eq. (3) at states s = (q, q̇) (..., 2n) of a batch-aware scalar L(s).

    ∇L comes from one batched grad; the Hessian rows from n + 1 vector products with it,
    vmapped over the vectors only (reverse over reverse, ~25% faster here than forward over
    reverse): (q̇, 0) gives (∇_q ∇_q̇ᵀ L) q̇ and (0, e_i) the rows of ∇_q̇ ∇_q̇ᵀ L.
    """
    n = s.shape[-1] // 2
    qd = s[..., n:]
    units = torch.eye(2 * n, dtype=s.dtype, device=s.device)[n:].reshape(n, *[1] * (s.dim() - 1), 2 * n)
    vectors = torch.cat([torch.cat([qd, torch.zeros_like(qd)], -1)[None], units.expand(n, *s.shape)])
    dl, pullback = vjp(lambda u: batched_grad(lagrangian, u), s)
    (rows,) = vmap(pullback)(vectors)
    hessian_vv = rows[1:, ..., n:].movedim(0, -2)  # a learned L may make it singular: inf, not an error
    return torch.linalg.solve_ex(hessian_vv, dl[..., :n] - rows[0, ..., n:])[0]


class LNN(DynamicsModel):
    """Unstructured L(q, q̇) network, eq. (3) (Cranmer et al. 2020)."""

    default_chart = "angle"

    def __init__(self, system: System, chart: str | None = None, hidden: int = 256, depth: int = 3,
                 activation: str = "softplus", angular: bool = False):
        super().__init__(system, chart)
        self.angular = angular
        self.lagrangian_net = mlp(3 * self.n if self.angular else 2 * self.n, 1, hidden, depth, activation)

    def lagrangian(self, s: Tensor) -> Tensor:
        """L(q, q̇) of states (..., 2n)."""
        q, qd = split_state(s)
        return self.lagrangian_net(torch.cat([embed_angles(q, self.angular), qd], -1)).squeeze(-1)

    def forward(self, t: Tensor, s: Tensor) -> Tensor:
        return torch.cat([split_state(s)[1], euler_lagrange_acceleration(self.lagrangian, s)], -1)



class LNNStructure(MassPotentialModel):
    """L = ½ q̇ᵀ M(q) q̇ − V(q) with learned M and V, eq. (5) (DeLaN, Lutter et al. 2019).

    q̈ = M⁻¹ [−Ṁ q̇ + ½ ∇_q(q̇ᵀ M q̇) − ∇V]: one batched grad of q ↦ ½ q̇ᵀ M(q) q̇ − V(q) at
    fixed q̇, whose M and Ṁ = dM/dt along q̇ come from one jvp of M inside it (one M forward).
    """

    def lagrangian(self, s: Tensor) -> Tensor:
        """L(q, q̇) of states (..., 2n)."""
        q, qd = split_state(s)
        return 0.5 * (qd * (self.mass(q) @ qd.unsqueeze(-1)).squeeze(-1)).sum(-1) - self.potential(q)

    def forward(self, t: Tensor, s: Tensor) -> Tensor:
        q, qd = split_state(s)

        def lagrangian(qi: Tensor) -> tuple[Tensor, tuple[Tensor, Tensor]]:
            mass, mass_dot = jvp(self.mass, (qi,), (qd,))
            kinetic = 0.5 * (qd * (mass @ qd.unsqueeze(-1)).squeeze(-1)).sum(-1)
            return (kinetic - self.potential(qi)).sum(), (mass, mass_dot)

        dl_dq, (mass, mass_dot) = grad(lagrangian, has_aux=True)(q)
        rhs = dl_dq - (mass_dot @ qd.unsqueeze(-1)).squeeze(-1)
        return torch.cat([qd, torch.linalg.solve(mass, rhs)], -1)

