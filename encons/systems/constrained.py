"""Dynamics under holonomic constraints Φ(x) = 0 with a constant mass matrix.

Shared by the true Cartesian fields of the systems and by the models that learn V and the
masses (CLNN, CHNN), so the equations are written once. Jacobians of Φ through ``torch.func``;
Φ takes any leading batch shape, as every ``System`` function does. Distance and linear
constraints declared as structure (``DistanceConstraints``) get DΦ, D_xΦ̇ in closed form.
Lagrangian form on s = (x, ẋ): eq. (15); Hamiltonian form on z = (x, p), p = M ẋ: eq. (20).
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch
from torch import Tensor
from torch.func import grad


Constraint = Callable[[Tensor], Tensor]
MatVec = Callable[[Tensor], Tensor]


def constraint_jacobians(phi: Constraint, x: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
    """DΦ(x) and D_x Φ̇ = ∂/∂x (DΦ(x) v) at fixed v, each (..., K, D).

    Reverse mode over K copies of x, copy k pulling back the k-th constraint: two nested
    ``grad`` calls in all (forward mode over the D directions costs ~4× more here).
    """
    k = phi(x.reshape(-1, x.shape[-1])[:1]).shape[-1]
    pick = torch.eye(k, dtype=x.dtype, device=x.device).reshape(k, *[1] * (x.dim() - 1), k)

    def rate(copies: Tensor) -> tuple[Tensor, Tensor]:
        rows = grad(lambda y: (phi(y) * pick).sum())(copies)
        return (rows * v).sum(), rows

    d_rate, jac = grad(rate, has_aux=True)(x.expand(k, *x.shape))
    return jac.movedim(0, -2), d_rate.movedim(0, -2)


class DistanceConstraints:
    """Φ(x) = (|x_i − x_j|² − l²_ij over ``edges``, then A x) on points of ``dim`` coordinates.

    ``edges`` (i, j) index points, j = −1 meaning the fixed origin (a pivot); ``linear`` is A
    (K_l, D), e.g. a rigid body's pivot point, may have no rows. Callable as Φ itself. Closed
    forms (``jacobians``): row k of DΦ is 2 (x_i − x_j) at point i and its negative at point j,
    and D_xΦ̇ (Φ̇ = 2 (x_i − x_j)·(v_i − v_j)) the same on velocities; linear rows are A and 0.
    Both through one constant incidence matrix E (K_d, n_points): differences are E @ points.
    """

    def __init__(self, n_points: int, dim: int, edges: Sequence[tuple[int, int]], lengths: Sequence[float],
                 linear: Tensor | None = None):
        self.dim = dim
        incidence = torch.zeros(len(edges), n_points, dtype=torch.float64)
        for k, (i, j) in enumerate(edges):  # once, at build
            incidence[k, i] += 1.0
            if j >= 0:
                incidence[k, j] -= 1.0
        self.incidence = incidence
        self.lengths_sq = torch.as_tensor(lengths, dtype=torch.float64) ** 2
        self.linear = torch.zeros(0, n_points * dim, dtype=torch.float64) if linear is None else linear.double()

    def _differences(self, y: Tensor) -> Tensor:
        return self.incidence.to(y) @ y.unflatten(-1, (self.incidence.shape[1], self.dim))

    def __call__(self, x: Tensor) -> Tensor:
        """Φ(x), shape (..., K)."""
        distance = self._differences(x).square().sum(-1) - self.lengths_sq.to(x)
        return torch.cat([distance, x @ self.linear.to(x).T], -1)

    def jacobians(self, x: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        """DΦ(x) and D_xΦ̇ at velocities v, each (..., K, D), in closed form."""
        spread = 2.0 * self.incidence.to(x)[:, :, None]  # (K_d, n_points, 1)
        linear = self.linear.to(x).expand(*x.shape[:-1], *self.linear.shape)
        jac = (spread * self._differences(x)[..., :, None, :]).flatten(-2)
        d_rate = (spread * self._differences(v)[..., :, None, :]).flatten(-2)
        return torch.cat([jac, linear], -2), torch.cat([d_rate, torch.zeros_like(linear)], -2)


def jacobians(phi: Constraint, x: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
    """DΦ(x), D_xΦ̇ (..., K, D): closed form for ``DistanceConstraints``, else autodiff."""
    if isinstance(phi, DistanceConstraints):
        return phi.jacobians(x, v)
    return constraint_jacobians(phi, x, v)


def constrained_acceleration(
    x: Tensor, v: Tensor, minv: MatVec, grad_v: Tensor, phi: Constraint
) -> Tensor:
    """ẍ of Zhong et al. eq. (15): Lagrangian dynamics with explicit constraints.

    ``minv`` applies the constant inverse mass matrix to vectors (..., D); ``grad_v`` is ∇V(x).
    """
    jac, d_rate = jacobians(phi, x, v)
    minv_grad = minv(grad_v)
    minv_jt = minv(jac)  # rows of DΦ M⁻¹ = (M⁻¹ DΦᵀ)ᵀ, M symmetric
    gram = jac @ minv_jt.transpose(-1, -2)
    rhs = ((jac @ minv_grad.unsqueeze(-1)) - d_rate @ v.unsqueeze(-1)).squeeze(-1)
    lam = torch.linalg.solve(gram, rhs)
    return (minv_jt.transpose(-1, -2) @ lam.unsqueeze(-1)).squeeze(-1) - minv_grad


def constrained_hamiltonian_field(grad_h: Tensor, jac: Tensor, d_rate: Tensor, minv: MatVec) -> Tensor:
    """ż of Zhong et al. eq. (20) on z = (x, p): J∇H minus its part that would leave Ψ(z) = 0.

    ``grad_h`` is ∇H (..., 2D). Ψ = (Φ(x), DΦ(x) M⁻¹ p) (§2.4) enters through the blocks of
    DΨ = [[A, 0], [C, A M⁻¹]]: ``jac`` A = DΦ and ``d_rate`` C = D_x Φ̇ (..., K, D), with
    ``minv`` applying the constant M⁻¹. Then DΨ J DΨᵀ = [[0, S], [−S, W]] with S = A M⁻¹ Aᵀ and
    W = C M⁻¹ Aᵀ − A M⁻¹ Cᵀ, and eq. (20) needs one K × K solve (K + 2 right-hand sides)
    instead of a 2K × 2K one: λ₂ = S⁻¹ A ∇_p H, λ₁ = S⁻¹ (W λ₂ − C ∇_p H + A M⁻¹ ∇_x H),
    ẋ = ∇_p H − M⁻¹ Aᵀ λ₂, ṗ = −∇_x H + Aᵀ λ₁ + Cᵀ λ₂.
    """
    grad_x, grad_p = grad_h.chunk(2, -1)
    jac_minv = minv(jac)  # rows of A M⁻¹ (M symmetric)
    cross = d_rate @ jac_minv.transpose(-1, -2)
    b_1 = jac @ grad_p.unsqueeze(-1)
    b_2 = d_rate @ grad_p.unsqueeze(-1) - jac_minv @ grad_x.unsqueeze(-1)
    solved = torch.linalg.solve(jac @ jac_minv.transpose(-1, -2),
                                torch.cat([b_1, b_2, cross - cross.transpose(-1, -2)], -1))
    lam_2 = solved[..., :1]
    lam_1 = solved[..., 2:] @ lam_2 - solved[..., 1:2]
    dx = grad_p - (jac_minv.transpose(-1, -2) @ lam_2).squeeze(-1)
    dp = -grad_x + (torch.cat([jac, d_rate], -2).transpose(-1, -2) @ torch.cat([lam_1, lam_2], -2)).squeeze(-1)
    return torch.cat([dx, dp], -1)
