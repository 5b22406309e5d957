"""L-NODE (Santos, Ekal & Ventura §4): learned M(q), V(q) in the forced Euler–Lagrange equation (4).

    q̈ = M(q)⁻¹ (B u − Ṁ q̇ + ½ ∇_q(q̇ᵀ M q̇) − ∇V(q)),

a continuous field rolled out by the ``integrator`` group (the paper's RK4 and midpoint), inputs u
held over each data step. M = L Lᵀ through a Cholesky factor, the system's angles embedded as
(cos q, sin q) when ``angular``; the input force is g(q) u (``encons.models.inputs``): the system's
constant B (``input_matrix=known``, the paper's control-affine form) or a learned g(q) (``learned``).
"""

from __future__ import annotations

from typing import Callable, cast

import torch
from torch import Tensor
from torch.func import grad, jvp

from encons.infra.bounds import Count
from encons.models import inputs
from encons.models.base import DynamicsModel, EnergyStructure, angle_mask
from encons.models.parts import CholeskyMass, Potential
from encons.systems.base import System, split_state


class LNode(DynamicsModel):
    """M(q) and V(q) networks (tanh 2 × 128 by default, Santos et al. §7) in eq. (4)."""

    default_chart = "angle"
    supports_controls = True
    family = "mass_matrix"  # learns M(q) and V(q), as the structured models do

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 128,
        depth: Count = 2,
        activation: str = "tanh",
        mass_eps: float = 1e-3,
        angular: bool = True,
        input_matrix: str = "known",
    ):
        super().__init__(system, chart)
        angles = angle_mask(system, angular)
        self.mass = CholeskyMass(self.n, angles, hidden, depth, activation, mass_eps)
        self.potential = Potential(self.n, angles, hidden, depth, activation)
        self.input_matrix = inputs.input_matrix(system, input_matrix, self.n, angles, hidden, depth, activation)

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        return forced_euler_lagrange(self.mass, self.potential, self.input_matrix, s, u)

    def energy_structure(self) -> EnergyStructure:
        """Its M(q), V(q) and input matrix: the energy-based controller's structure (``encons.tools.control``)."""
        return EnergyStructure(self.mass, self.potential, self.input_matrix)


def forced_euler_lagrange(
    mass: Callable[[Tensor], Tensor],
    potential: Callable[[Tensor], Tensor],
    input_matrix: Tensor | Callable[[Tensor], Tensor] | None,
    s: Tensor,
    u: Tensor | None = None,
) -> Tensor:
    """ds/dt of eq. (4) for any M(q) (``mass``), V(q) (``potential``) and input matrix (``input_matrix``:
    a constant B (n, m) or a function q ↦ g(q) (..., n, m)): L-NODE's field, and the continuous
    Euler–Lagrange equations of the learned M and V of SyMo and the structured models (``encons.tools.control``)."""
    q, qd = split_state(s)

    def lagrangian(qi: Tensor) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        m, m_dot = cast("tuple[Tensor, Tensor]", jvp(mass, (qi,), (qd,)))  # M and Ṁ = dM/dt along q̇ from one jvp
        kinetic = 0.5 * (qd * (m @ qd.unsqueeze(-1)).squeeze(-1)).sum(-1)
        return (kinetic - potential(qi)).sum(), (m, m_dot)

    dl_dq, (m, m_dot) = grad(lagrangian, has_aux=True)(q)
    rhs = dl_dq - (m_dot @ qd.unsqueeze(-1)).squeeze(-1)
    if u is not None:
        assert input_matrix is not None  # inputs reach only a model built for a system with controls
        g = input_matrix(q) if callable(input_matrix) else input_matrix.to(s)
        rhs = rhs + (g @ u.to(s).unsqueeze(-1)).squeeze(-1)
    return torch.cat([qd, torch.linalg.solve_ex(m, rhs)[0]], -1)  # singular (diverged): nan, not an exception
