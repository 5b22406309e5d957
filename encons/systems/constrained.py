"""Dynamics under holonomic constraints Φ(x) = 0 with a constant mass matrix.

Shared by the true Cartesian fields of the systems and by the models that learn V and the
masses (CLNN, CHNN), so the equations are written once. Jacobians of Φ through ``torch.func``;
Φ takes any leading batch shape, as every ``System`` function does. Distance and linear
constraints declared as structure (``DistanceConstraints``) get DΦ, D_xΦ̇ in closed form, and
their constant linear rows are eliminated exactly into a projected M⁻¹ (``eliminate_linear``), so
the batched solves are over the distance rows only (gyroscope: 6 × 6 instead of 9 × 9).
Lagrangian form on s = (x, ẋ): eq. (15); Hamiltonian form on z = (x, p), p = M ẋ: eq. (20).
Solves are ``torch.linalg.solve_ex``: a singular system (degenerate constraints) gives inf/nan,
which training reports as divergence, and the per-call error check is skipped.
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch
from torch import Tensor
from torch.func import grad

from encons.infra.batching import product

Constraint = Callable[[Tensor], Tensor]


def constraint_jacobians(phi: Constraint, x: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
    """DΦ(x) and D_x Φ̇ = ∂/∂x (DΦ(x) v) at fixed v, each (..., K, D).

    Reverse mode over K copies of x, copy k pulling back the k-th constraint: two nested
    ``grad`` calls in all (forward mode would take one pass per coordinate, D of them).
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
    Both through one constant incidence matrix E (K_d, n_points): differences are E @ points,
    computed as one matmul with Eᵀ ⊗ I over the flattened coordinates.
    """

    def __init__(
        self,
        n_points: int,
        dim: int,
        edges: Sequence[tuple[int, int]],
        lengths: Sequence[float],
        linear: Tensor | None = None,
    ):
        self.dim = dim
        incidence = torch.zeros(len(edges), n_points, dtype=torch.float64)
        for k, (i, j) in enumerate(edges):  # once, at build
            incidence[k, i] += 1.0
            if j >= 0:
                incidence[k, j] -= 1.0
        self.incidence = incidence
        self.coords = torch.kron(incidence.T.contiguous(), torch.eye(dim, dtype=torch.float64))  # Eᵀ ⊗ I (D, K_d·dim)
        self.lengths_sq = torch.as_tensor(lengths, dtype=torch.float64) ** 2
        self.linear = torch.zeros(0, n_points * dim, dtype=torch.float64) if linear is None else linear.double()
        self._cache: dict[tuple, tuple[Tensor, Tensor, Tensor, Tensor]] = {}

    def _constants(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Eᵀ ⊗ I (D, K_d·dim), l², A and 2E (K_d, n_points, 1) in ``like``'s dtype and device, converted once."""
        key = (like.dtype, like.device)
        if key not in self._cache:
            self._cache[key] = (
                self.coords.to(like),
                self.lengths_sq.to(like),
                self.linear.to(like),
                2.0 * self.incidence.to(like)[:, :, None],
            )
        return self._cache[key]

    def _differences(self, y: Tensor) -> Tensor:
        """The edge vectors E y (..., K_d, dim) of point coordinates y (..., D): one matmul over the
        flattened batch (not a broadcast one, a batched matmul of tiny matrices)."""
        return (y @ self._constants(y)[0]).unflatten(-1, (-1, self.dim))

    def __call__(self, x: Tensor) -> Tensor:
        """Φ(x), shape (..., K)."""
        _, lengths_sq, linear, _ = self._constants(x)
        distance = self._differences(x).square().sum(-1) - lengths_sq
        return torch.cat([distance, x @ linear.T], -1)

    def jacobians(self, x: Tensor, v: Tensor, linear_rows: bool = True) -> tuple[Tensor, Tensor]:
        """DΦ(x) and D_xΦ̇ at velocities v, each (..., K, D), in closed form; the distance rows
        alone (K_d) if not ``linear_rows``."""
        _, _, linear, spread = self._constants(x)  # spread: (K_d, n_points, 1)
        jac = (spread * self._differences(x)[..., :, None, :]).flatten(-2)
        d_rate = (spread * self._differences(v)[..., :, None, :]).flatten(-2)
        if not (len(linear) and linear_rows):
            return jac, d_rate
        linear = linear.expand(*x.shape[:-1], *linear.shape)
        return torch.cat([jac, linear], -2), torch.cat([d_rate, torch.zeros_like(linear)], -2)

    def eliminate_linear(self, minv: Tensor) -> tuple[Tensor, Tensor | None]:
        """M_P⁻¹ = P₂ M⁻¹ and P₂ = I − M⁻¹A₂ᵀ(A₂M⁻¹A₂ᵀ)⁻¹A₂ (D, D) for the linear rows A₂ and the
        constant ``minv`` (D, D) (member-stacked (members, D, D): each so); (``minv``, None) without linear rows.

        P₂ is the M-orthogonal projection onto null(A₂). Eliminating λ₂ of the constant rows (their
        D_xΦ̇ is 0) by the Schur complement leaves eq. (15) over the distance rows with M_P⁻¹ in
        place of M⁻¹, exactly, on and off Φ = 0; eq. (20) likewise (``constrained_hamiltonian_field``).
        """
        linear = self._constants(minv)[2]
        if not len(linear):
            return minv, None
        scaled = minv @ linear.T  # M⁻¹A₂ᵀ (D, K_l)
        gain = torch.linalg.solve_ex(linear @ scaled, linear)[0]  # S₂₂⁻¹A₂ (K_l, D); S₂₂ ≻ 0
        project = torch.eye(minv.shape[-1], dtype=minv.dtype, device=minv.device) - scaled @ gain
        return project @ minv, project


def eliminate_linear(phi: Constraint, minv: Tensor) -> tuple[Tensor, Tensor | None]:
    """(M_P⁻¹, P₂) of Φ's constant linear rows (``DistanceConstraints.eliminate_linear``), or
    (``minv``, None) for a Φ that declares none (any other callable)."""
    if isinstance(phi, DistanceConstraints):
        return phi.eliminate_linear(minv)
    return minv, None


def jacobians(phi: Constraint, x: Tensor, v: Tensor, linear_rows: bool = True) -> tuple[Tensor, Tensor]:
    """DΦ(x), D_xΦ̇ (..., K, D): closed form for ``DistanceConstraints`` (without its linear rows
    if not ``linear_rows``: they were eliminated), else every row by autodiff."""
    if isinstance(phi, DistanceConstraints):
        return phi.jacobians(x, v, linear_rows)
    return constraint_jacobians(phi, x, v)


def full_mass_matrix(mp: Tensor, dim: int) -> Tensor:
    """kron(``mp``, I_dim): a matrix over points (n_points, n_points) as one over coordinates (D, D); member-stacked
    (members, n_points, n_points) gives (members, D, D)."""
    eye = torch.eye(dim, dtype=mp.dtype, device=mp.device)
    rows, cols = mp.shape[-2:]
    return (mp[..., :, None, :, None] * eye[:, None, :]).reshape(*mp.shape[:-2], rows * dim, cols * dim)


def constrained_acceleration(
    x: Tensor, v: Tensor, minv: Tensor, grad_v: Tensor, phi: Constraint, eliminated: bool = False
) -> Tensor:
    """ẍ of Zhong et al. eq. (15): Lagrangian dynamics with explicit constraints.

    ``minv`` is the constant inverse mass matrix (D, D) (``full_mass_matrix``; or member-stacked,
    ``encons.infra.batching.product``); ``grad_v`` is ∇V(x).
    ẍ = M⁻¹ Aᵀ λ − M⁻¹ ∇V with (A M⁻¹ Aᵀ) λ = A M⁻¹ ∇V − C v, A = DΦ, C = D_xΦ̇; the products
    with M⁻¹ and with A are one matmul each. Constant linear rows of Φ enter through M_P⁻¹
    (``eliminate_linear``), which gives the same ẍ; ``eliminated``: ``minv`` already is M_P⁻¹
    (computed once per rollout).
    """
    if not eliminated:
        minv = eliminate_linear(phi, minv)[0]
    jac, d_rate = jacobians(phi, x, v, linear_rows=False)  # the linear rows are in M_P⁻¹
    k = jac.shape[-2]
    scaled = product(torch.cat([jac, grad_v.unsqueeze(-2)], -2), minv)  # rows of A M⁻¹, then (M⁻¹ ∇V)ᵀ (M symmetric)
    prod = torch.cat([jac, d_rate], -2) @ torch.cat([scaled, v.unsqueeze(-2)], -2).transpose(-1, -2)
    lam = torch.linalg.solve_ex(prod[..., :k, :k], prod[..., :k, k] - prod[..., k:, k + 1])[0]
    return (lam.unsqueeze(-1) * scaled[..., :k, :]).sum(-2) - scaled[..., k, :]  # a K-term sum: no tiny bmm


def constrained_hamiltonian_field(
    grad_h: Tensor, jac: Tensor, d_rate: Tensor, minv: Tensor, project: Tensor | None = None
) -> Tensor:
    """ż of Zhong et al. eq. (20) on z = (x, p): J∇H minus its part that would leave Ψ(z) = 0.

    ``grad_h`` is ∇H (..., 2D). Ψ = (Φ(x), DΦ(x) M⁻¹ p) (§2.4) enters through the blocks of
    DΨ = [[A, 0], [C, A M⁻¹]]: ``jac`` A = DΦ and ``d_rate`` C = D_x Φ̇ (..., K, D), with
    ``minv`` the constant M⁻¹ (D, D) (or member-stacked, ``encons.infra.batching.product``). Then
    DΨ J DΨᵀ = [[0, S], [−S, W]] with S = A M⁻¹ Aᵀ and W = C M⁻¹ Aᵀ − A M⁻¹ Cᵀ, and eq. (20) needs one
    K × K solve (K + 2 right-hand sides) instead of a 2K × 2K one: λ₂ = S⁻¹ A ∇_p H,
    λ₁ = S⁻¹ (W λ₂ − C ∇_p H + A M⁻¹ ∇_x H), ẋ = ∇_p H − M⁻¹ Aᵀ λ₂, ṗ = −∇_x H + Aᵀ λ₁ + Cᵀ λ₂. The
    products with [A; C] are one batched matmul; those with the multipliers, K-term sums.
    Constant linear rows A₂ eliminated (``eliminate_linear``: ``project`` P₂, ``minv`` M_P⁻¹, A and
    C of the other rows, C still at v = M⁻¹p): pass ∇_pH projected, P₂ ∇_pH (for H: M_P⁻¹ p), and
    ṗ comes out as P₂ᵀ(−∇_xH + Aᵀλ₁ + Cᵀλ₂), the same ż as with every row: the symplectic
    projection onto the constant rows, diag(P₂, P₂ᵀ), factors out of eq. (20) (tested).
    """
    grad_x, grad_p = grad_h.chunk(2, -1)
    k = jac.shape[-2]
    rows = torch.cat([jac, d_rate], -2)  # [A; C]
    scaled = product(torch.cat([jac, grad_x.unsqueeze(-2)], -2), minv)  # rows of A M⁻¹, then (M⁻¹ ∇_x H)ᵀ
    prod = rows @ torch.cat([grad_p.unsqueeze(-2), scaled], -2).transpose(-1, -2)  # [A; C] [∇_pH, M⁻¹Aᵀ, M⁻¹∇_xH]
    cross = prod[..., k:, 1 : k + 1]  # C M⁻¹ Aᵀ
    rhs = torch.cat(
        [prod[..., :k, :1], prod[..., k:, :1] - prod[..., :k, k + 1 :], cross - cross.transpose(-1, -2)], -1
    )
    solved = torch.linalg.solve_ex(prod[..., :k, 1 : k + 1], rhs)[0]
    lam_2 = solved[..., :1]
    lam_1 = solved[..., 2:] @ lam_2 - solved[..., 1:2]
    # Aᵀλ₁ + Cᵀλ₂ and Aᵀλ₂ as K-term broadcast sums, not as one batched matmul of tiny matrices
    p_dot = (lam_1 * jac + lam_2 * d_rate).sum(-2) - grad_x
    return torch.cat(
        [grad_p - product((lam_2 * jac).sum(-2), minv), p_dot if project is None else product(p_dot, project)], -1
    )
