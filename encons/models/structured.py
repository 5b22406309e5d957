"""Shared base of the structured models: learned M(q) = L Lᵀ and V(q) (Zhong et al. eqs. (4), (8))."""

from __future__ import annotations

from torch import Tensor

from encons.infra.bounds import Count
from encons.models import inputs
from encons.models.base import DynamicsModel, EnergyStructure, angle_mask
from encons.models.parts import CholeskyMass, Potential
from encons.systems.base import System


class MassPotentialModel(DynamicsModel):
    """Learns the Cholesky factor L(q) of M(q) (``mass``: ``forward``/``solve``) and V(q); "-angle" via ``angular``
    (the system's angles on S¹, translations such as the cart's position as they are).

    ``shared_trunk=True`` (default): one ``depth`` × ``hidden`` network with n(n+1)/2 + 1 outputs
    gives L(q) and V(q), so a field evaluation runs one network instead of two (about half the
    cost). ``False``: two separate networks as in Zhong et al. (SymODEN, DeLaN).
    Fields get both through ``factor_potential``. On a system with inputs u, the generalised force
    g(q) u enters as in Symplectic ODE-Net (``encons.models.inputs``; ``input_matrix=known|learned``).
    """

    default_chart = "angle"
    family = "mass_matrix"

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 256,
        depth: Count = 3,
        activation: str = "softplus",
        mass_eps: float = 1e-3,
        angular: bool = False,
        shared_trunk: bool = True,
        input_matrix: str = "known",
    ):
        super().__init__(system, chart)
        self.angular, self.shared_trunk = angle_mask(system, angular), shared_trunk
        self.mass = CholeskyMass(self.n, self.angular, hidden, depth, activation, mass_eps, extra=int(shared_trunk))
        if not shared_trunk:
            self.potential_net = Potential(self.n, self.angular, hidden, depth, activation)
        self.input_matrix = inputs.input_matrix(system, input_matrix, self.n, self.angular, hidden, depth, activation)

    def factor_potential(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """L(q) (..., n, n) and V(q) (...): one network forward with the shared trunk."""
        if self.shared_trunk:
            factor, extra = self.mass.factor(q)
            return factor, extra.squeeze(-1)
        return self.mass.cholesky(q), self.potential_net(q)

    def potential(self, q: Tensor) -> Tensor:
        """V(q)."""
        return self.factor_potential(q)[1]

    def energy_structure(self) -> EnergyStructure:
        """Its M(q), V(q) and input matrix: the energy-based controller's structure (``encons.tools.control``)."""
        return EnergyStructure(self.mass, self.potential, self.input_matrix)
