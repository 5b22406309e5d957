"""Mechanical systems in generalised coordinates moved by a generalised force.

The state is s = (q, q̇) (one chart, ``angle``); each system gives M(q), V(q) and
b(q, q̇) = C(q, q̇) + ∇V(q) (Coriolis/centrifugal terms and gravity) in closed form, and moves by

    M(q) q̈ = F(s, u) − b(q, q̇),

with F the non-conservative force of Xiao et al. eq. (2) (``dissipative``) or the input force B u
of Santos et al. eq. (4) (``controlled``). E = ½ q̇ᵀ M q̇ + V and L = ½ q̇ᵀ M q̇ − V.
"""

from __future__ import annotations

import abc

import torch
from torch import Tensor

from encons.systems.base import System, split_state


class Mechanical(System):
    """Base: M(q), V(q), b(q, q̇) in closed form and the generalised force F(s, u)."""

    charts = ("angle",)
    common_chart = "angle"
    n: int

    def coord_dim(self, chart: str) -> int:
        self.check_chart(chart)
        return self.n

    @abc.abstractmethod
    def mass_matrix(self, q: Tensor) -> Tensor: ...

    @abc.abstractmethod
    def potential(self, q: Tensor) -> Tensor: ...

    @abc.abstractmethod
    def bias(self, q: Tensor, qd: Tensor) -> Tensor:
        """b(q, q̇) = C(q, q̇) + ∇V(q), so that M q̈ = F − b."""

    @abc.abstractmethod
    def generalised_force(self, s: Tensor, u: Tensor | None) -> Tensor | None:
        """F(s, u) (..., n), or None where it vanishes."""

    def vector_field(self, s: Tensor, chart: str, u: Tensor | None = None) -> Tensor:
        self.check_chart(chart)
        q, qd = split_state(s)
        force = self.generalised_force(s, u)
        rhs = -self.bias(q, qd) if force is None else force - self.bias(q, qd)
        return torch.cat([qd, torch.linalg.solve(self.mass_matrix(q), rhs.unsqueeze(-1)).squeeze(-1)], -1)

    def kinetic(self, q: Tensor, qd: Tensor) -> Tensor:
        return 0.5 * (qd[..., None, :] @ self.mass_matrix(q) @ qd[..., :, None])[..., 0, 0]

    def lagrangian(self, s: Tensor) -> Tensor:
        """L = ½ q̇ᵀ M(q) q̇ − V(q) (Xiao et al. Lemma 1: L = T − U)."""
        q, qd = split_state(s)
        return self.kinetic(q, qd) - self.potential(q)

    def energy(self, s: Tensor, chart: str) -> Tensor:
        self.check_chart(chart)
        q, qd = split_state(s)
        return self.kinetic(q, qd) + self.potential(q)
