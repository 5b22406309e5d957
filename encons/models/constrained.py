"""Models with explicit constraints on the Cartesian chart (Finzi et al. 2020; Zhong et al. §2.3–2.4).

Both learn a potential V(x) and constant positive masses structured by the system's bodies
(``PointMasses``), and take the system's known holonomic constraints Φ(x) = 0. The mass
matrix is kron(Mp, I_dim) over the (n_points, n_points) matrix Mp; only Mp is ever inverted, in
closed form, once per rollout (``rollout_scope``), not per field evaluation.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import torch
from torch import Tensor

from encons.infra.batching import product
from encons.infra.bounds import Count
from encons.models.base import DynamicsModel
from encons.models.networks import MLPTape
from encons.models.parts import PointMasses, Potential
from encons.systems.base import System, split_state
from encons.systems.constrained import (
    constrained_acceleration,
    constrained_hamiltonian_field,
    eliminate_linear,
    full_mass_matrix,
    jacobians,
)


class CartesianModel(DynamicsModel):
    """Learned V(x) and body masses, with the system's constraints and Cartesian layout."""

    default_chart = "cartesian"
    needs_constraints = True
    family = "constrained"

    def __init__(self, system: System, hidden: Count = 256, depth: Count = 3, activation: str = "softplus"):
        super().__init__(system)
        assert system.layout is not None  # needs_constraints: the checker admits only systems with a Cartesian layout
        self.dim = system.layout.dim
        self.constraints = system.constraints
        self.potential_net = Potential(self.n, False, hidden, depth, activation)
        self.masses = PointMasses(system.layout)
        self._mass_terms: tuple[Tensor, Tensor, Tensor | None] | None = None

    @contextmanager
    def rollout_scope(self) -> Iterator[None]:
        """M⁻¹ and the constraint-projected M_P⁻¹, P once for the whole rollout (one autograd node
        shared by every field evaluation)."""
        self._mass_terms = self.mass_terms()
        try:
            yield
        finally:
            self._mass_terms = None

    def mass_terms(self) -> tuple[Tensor, Tensor, Tensor | None]:
        """(M⁻¹, M_P⁻¹, P) (D, D): M⁻¹ = kron(Mp⁻¹, I) and its projection by the constant linear
        constraint rows (``eliminate_linear``; M⁻¹ and None without them);
        the rollout's copy inside ``rollout_scope``."""
        if self._mass_terms is not None:
            return self._mass_terms
        minv = full_mass_matrix(self.point_masses_inverse(), self.dim)
        return minv, *eliminate_linear(self.constraints, minv)

    def potential(self, x: Tensor) -> Tensor:
        """V(x)."""
        return self.potential_net(x)

    def point_masses(self) -> Tensor:
        """The (n_points, n_points) mass matrix Mp over points."""
        return self.masses()

    def point_masses_inverse(self) -> Tensor:
        """Mp⁻¹, in closed form (``PointMasses.inverse``)."""
        return self.masses.inverse()

    def potential_gradient(self, x: Tensor) -> Tensor:
        """∇V(x) through the network in closed form (``MLPTape``: one forward, one explicit backward)."""
        tape = MLPTape(self.potential_net.net, x)
        return tape.pullback()


class CLNN(CartesianModel):
    """Constrained Lagrangian dynamics on s = (x, ẋ), Zhong et al. eq. (15) (Finzi et al. 2020)."""

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        x, v = split_state(s)
        minv_p = self.mass_terms()[1]
        acc = constrained_acceleration(x, v, minv_p, self.potential_gradient(x), self.constraints, eliminated=True)
        return torch.cat([v, acc], -1)


class CHNN(CartesianModel):
    """Constrained Hamiltonian dynamics on z = (x, p), p = M ẋ, Zhong et al. eq. (20) (Finzi et al. 2020)."""

    def to_internal(self, s: Tensor) -> Tensor:
        x, v = split_state(s)
        return torch.cat([x, product(v, full_mass_matrix(self.point_masses(), self.dim))], -1)

    def from_internal(self, z: Tensor) -> Tensor:
        x, p = split_state(z)
        return torch.cat([x, product(p, self.mass_terms()[0])], -1)

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        x, p = split_state(z)
        minv, minv_p, project = self.mass_terms()
        jac, d_rate = jacobians(
            self.constraints, x, product(p, minv), linear_rows=False
        )  # the linear rows are in M_P⁻¹
        grad_h = torch.cat([self.potential_gradient(x), product(p, minv_p)], -1)  # ∇_pH = M⁻¹p, projected (M_P⁻¹ p)
        return constrained_hamiltonian_field(grad_h, jac, d_rate, minv_p, project)
