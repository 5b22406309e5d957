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
from encons.errors import ConfigError
from encons.models.base import DynamicsModel
from encons.models.networks import cranmer_init_, embed_angles, mlp
from encons.models.structured import MassPotentialModel
from encons.systems.base import System, split_state


def euler_lagrange_acceleration(lagrangian: Callable[[Tensor], Tensor], s: Tensor, damping: float,
                                force: Tensor | None = None) -> Tensor:
    """q̈ of Zhong et al. eq. (3) at states s = (q, q̇) (..., 2n) of a batch-aware scalar L(s); with a
    non-conservative generalised ``force`` F (..., n), of the generalised Lagrange equation (Xiao et al. eq. (11)).

    ∇L comes from one batched grad; the Hessian rows from n + 1 vector products with it,
    vmapped over the vectors only (reverse over reverse, ~25% faster here than forward over
    reverse): (q̇, 0) gives (∇_q ∇_q̇ᵀ L) q̇ and (0, e_i) the rows of H = ∇_q̇ ∇_q̇ᵀ L.

    Guarded solve: a learned L has no reason to make H invertible (the true one is M(q) ≻ 0),
    and a plain solve turns a near-singular H into q̈ ~ 1e3 that RK4 blows up at step 0. So
    q̈ = argmin ‖H q̈ − r‖² + λ²‖q̈‖² = (HᵀH + λ²I)⁻¹ Hᵀ r (Tikhonov / damped least squares),
    λ = ``damping`` (units of L / q̇², i.e. mass): smooth in the parameters, |q̈| ≤ |r| / (2λ)
    whatever H, and equal to H⁻¹ r up to a relative O(λ² / σ_min(H)²). The bias is absolute,
    so training can scale L up past it; a floor relative to |H| could not be learned away.
    ``damping=0`` is the plain solve (inf/nan where H is singular).
    """
    n = s.shape[-1] // 2
    qd = s[..., n:]
    units = torch.eye(2 * n, dtype=s.dtype, device=s.device)[n:].reshape(n, *[1] * (s.dim() - 1), 2 * n)
    vectors = torch.cat([torch.cat([qd, torch.zeros_like(qd)], -1)[None], units.expand(n, *s.shape)])
    dl, pullback = vjp(lambda u: batched_grad(lagrangian, u), s)
    (rows,) = vmap(pullback)(vectors)
    hessian_vv = rows[1:, ..., n:].movedim(0, -2)
    rhs = dl[..., :n] - rows[0, ..., n:]
    if force is not None:
        rhs = rhs + force
    ht = hessian_vv.transpose(-1, -2)
    normal = ht @ hessian_vv + damping**2 * torch.eye(n, dtype=s.dtype, device=s.device)
    return torch.linalg.solve(normal, (ht @ rhs.unsqueeze(-1))).squeeze(-1)


#: Objectives of models whose field is (q̇, q̈) by construction: q̈ alone is a complete target
#: (``acceleration``, Xiao et al. §3), beside the rollout and full-derivative ones.
SECOND_ORDER_OBJECTIVES = ("rollout", "acceleration", "derivative")


class LNN(DynamicsModel):
    """Unstructured L(q, q̇) network, eq. (3) (Cranmer et al. 2020).

    The network starts from Cranmer et al.'s initialisation for LNN MLPs (``cranmer_init_``),
    which keeps ∇²_q̇ L O(1) at the paper's widths; q̈ takes the guarded solve of
    ``euler_lagrange_acceleration`` (that, not the init, is what keeps tiny runs finite).
    """

    default_chart = "angle"
    objectives = SECOND_ORDER_OBJECTIVES

    def __init__(self, system: System, chart: str | None = None, hidden: int = 256, depth: int = 3,
                 activation: str = "softplus", damping: float = 0.1, angular: bool = False):
        super().__init__(system, chart)
        if not damping >= 0:
            raise ConfigError(f"model.damping={damping} is negative; allowed: a float >= 0 (0: plain Hessian solve)")
        self.damping, self.angular = damping, angular
        self.lagrangian_net = cranmer_init_(mlp(3 * self.n if self.angular else 2 * self.n, 1, hidden, depth, activation))

    def lagrangian(self, s: Tensor) -> Tensor:
        """L(q, q̇) of states (..., 2n)."""
        q, qd = split_state(s)
        return self.lagrangian_net(torch.cat([embed_angles(q, self.angular), qd], -1)).squeeze(-1)

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        return torch.cat([split_state(s)[1], euler_lagrange_acceleration(self.lagrangian, s, self.damping)], -1)


class LNNStructure(MassPotentialModel):
    """L = ½ q̇ᵀ M(q) q̇ − V(q) with learned M = L_M L_Mᵀ and V, eq. (5) (DeLaN, Lutter et al. 2019).

    q̈ = M⁻¹ [−Ṁ q̇ + ½ ∇_q(q̇ᵀ M q̇) − ∇V]: one batched grad of q ↦ ½ q̇ᵀ M(q) q̇ − V(q) at
    fixed q̇; L_M and L̇_M along q̇ come from one jvp of the network inside it (one forward of
    the shared trunk gives V too), Ṁ = L̇_M L_Mᵀ + L_M L̇_Mᵀ, and M⁻¹ by the Cholesky factor.
    """

    objectives = SECOND_ORDER_OBJECTIVES

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        q, qd = split_state(s)

        def lagrangian(qi: Tensor) -> tuple[Tensor, tuple[Tensor, Tensor]]:
            if self.shared_trunk:
                (factor, potential), (factor_dot, _) = jvp(self.factor_potential, (qi,), (qd,))
            else:
                (factor, factor_dot), potential = jvp(self.mass.cholesky, (qi,), (qd,)), self.potential_net(qi)
            mass = factor @ factor.transpose(-1, -2)
            mass_dot = factor_dot @ factor.transpose(-1, -2) + factor @ factor_dot.transpose(-1, -2)
            kinetic = 0.5 * (qd * (mass @ qd.unsqueeze(-1)).squeeze(-1)).sum(-1)
            return (kinetic - potential).sum(), (factor, mass_dot)

        dl_dq, (factor, mass_dot) = grad(lagrangian, has_aux=True)(q)
        rhs = dl_dq - (mass_dot @ qd.unsqueeze(-1)).squeeze(-1)
        return torch.cat([qd, torch.cholesky_solve(rhs.unsqueeze(-1), factor).squeeze(-1)], -1)
