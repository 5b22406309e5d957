"""Dynamics under holonomic constraints Φ(x) = 0 with a constant mass matrix.

Shared by the true Cartesian fields of the systems and by the models that learn V and the
masses (CLNN, CHNN), so the equations are written once. Jacobians of Φ through ``torch.func``.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor
from torch.func import jacfwd, jvp

from encons.batching import batched
Constraint = Callable[[Tensor], Tensor]
MatVec = Callable[[Tensor], Tensor]


def constraint_jacobian(phi: Constraint, x: Tensor) -> Tensor:
    """DΦ(x), shape (..., K, D)."""
    return batched(jacfwd(phi), x)


def constraint_curvature(phi: Constraint, x: Tensor, v: Tensor) -> Tensor:
    """(D_x Φ̇) ẋ = d/dt(DΦ(x)) ẋ, the velocity-squared term of Φ̈; shape (..., K)."""

    def one(xi: Tensor, vi: Tensor) -> Tensor:
        return jvp(lambda y: jvp(phi, (y,), (vi,))[1], (xi,), (vi,))[1]

    return batched(one, x, v)


def constrained_acceleration(
    x: Tensor, v: Tensor, minv: MatVec, grad_v: Tensor, phi: Constraint
) -> Tensor:
    """ẍ of Zhong et al. eq. (15): Lagrangian dynamics with explicit constraints.

    ``minv`` applies the constant inverse mass matrix to vectors (..., D); ``grad_v`` is ∇V(x).
    """
    jac = constraint_jacobian(phi, x)
    minv_grad = minv(grad_v)
    minv_jt = minv(jac)  # rows of J M⁻¹ = (M⁻¹ Jᵀ)ᵀ, M symmetric
    gram = jac @ minv_jt.transpose(-1, -2)
    rhs = (jac @ minv_grad.unsqueeze(-1)).squeeze(-1) - constraint_curvature(phi, x, v)
    lam = torch.linalg.solve(gram, rhs)
    return (minv_jt.transpose(-1, -2) @ lam.unsqueeze(-1)).squeeze(-1) - minv_grad
